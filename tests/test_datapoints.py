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


def test_rim_points_lie_one_step_outside_a_box_on_the_face_it_pushes_to():
    """Eq. 4.16's middles pin the surface only inside a box's outline,
    and the C2 surface curls back up inside the box before the side face. `datapoints.rim_points`
    puts a point one detection step outside each side-face crossing, aimed at the bottom face's
    plane, so the rise happens outside. A curved collider's flank gives none (its plane extended
    past the outline would cut into what the ball needs: `elbow_contact`)."""
    import trimesh

    from acra import hspline as H
    from acra import shapes
    from pipeline import detect as D
    from pipeline.model import ColliderModel

    cvs, _, _ = shapes.sheet(12, 12, width=4.0, depth=4.0)
    sheet = geometry.SurfaceGeometry(H.from_grid(cvs, depth=3), np.eye(4), "/sheet")
    lo, hi = np.array([-0.7, -0.9, -0.5]), np.array([0.9, 0.7, 0.5])
    mesh = trimesh.creation.box(bounds=np.stack([lo, hi]))
    box = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/box", mesh.vertices, mesh.faces)), np.eye(4))
    region, _ = D.regions(sheet, box)
    down = np.array([0.0, 0.0, -1.0])
    uv, points, goals = P.rim_points(sheet, box, region.uv, down, 2)
    step = 4.0 / 9 / 8  # one detection step (8 per level-0 patch edge) in world units
    x, y = points[:, 0], points[:, 1]
    beyond = np.maximum.reduce([lo[0] - x, x - hi[0], lo[1] - y, y - hi[1]])
    assert len(uv) >= 4 * 3  # every side of the outline has rim points
    # outside, one step past the crossing (bisected to 1/64 of the step): measured 0.022 to 0.0561
    assert np.all(beyond > 0) and np.all(beyond <= step * (1 + 2.0**-P.RIM_BISECT) + 1e-9), beyond
    np.testing.assert_allclose(goals[:, :2], points[:, :2], atol=1e-12)  # moved along the push
    np.testing.assert_allclose(goals[:, 2], lo[2], atol=1e-9)  # onto the bottom face's plane
    for side in (x < lo[0], x > hi[0], y < lo[1], y > hi[1]):
        assert side.any()

    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.45)
    ball.apply_translation([0.1, -0.1, 0.3])  # 0.15 into the sheet
    ball_geom = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/ball", ball.vertices, ball.faces)), np.eye(4))
    region, _ = D.regions(sheet, ball_geom)
    assert len(region.uv) and len(P.rim_points(sheet, ball_geom, region.uv, down, 2)[0]) == 0


def test_rim_points_are_kept_by_content_and_never_served_for_other_content(monkeypatch):
    """`rim_points` keeps its answers by the pair's content, the region and the direction: a new
    sheet and box of the same content get the kept answer without bisecting again (and arrays of
    their own), a moved box or a changed CV (one ulp) a new answer equal to a fresh one, and at
    most `RIMS_KEPT` answers are kept."""
    import trimesh

    from acra import hspline as H
    from acra import shapes
    from pipeline import detect as D
    from pipeline.model import ColliderModel

    cvs, _, _ = shapes.sheet(12, 12, width=4.0, depth=4.0)
    hs = H.from_grid(cvs, depth=3)
    mesh = trimesh.creation.box(bounds=np.array([[-0.7, -0.9, -0.5], [0.9, 0.7, 0.5]]))
    static = geometry.prepare_collider(ColliderModel("/box", mesh.vertices, mesh.faces))
    down = np.array([0.0, 0.0, -1.0])

    def pair(surface=hs, dx=0.0):
        sheet = geometry.SurfaceGeometry(surface, np.eye(4), "/sheet")
        xform = np.eye(4)
        xform[0, 3] = dx
        box = geometry.ColliderGeometry(static, xform)
        return sheet, box, D.regions(sheet, box)[0].uv

    computed = []
    fresh = P._rim_points
    monkeypatch.setattr(P, "_rim_points", lambda *a: computed.append(1) or fresh(*a))
    P._RIMS.clear()
    sheet, box, uv = pair()
    first = P.rim_points(sheet, box, uv, down, 2)
    first[1][:] = np.nan  # the caller's arrays are its own
    again = P.rim_points(*pair(H.with_cvs(hs, hs.cvs.copy())), down, 2)
    assert len(computed) == 1 and len(again[0]) >= 12 and np.isfinite(again[1]).all()
    moved = P.rim_points(*pair(dx=0.25), down, 2)
    ulp = hs.cvs.copy()
    ulp[5, 5, 2] = np.nextafter(ulp[5, 5, 2], np.inf)
    changed = pair(H.with_cvs(hs, ulp))
    bumped = P.rim_points(*changed, down, 2)
    assert len(computed) == 3
    for got, want in ((moved, fresh(*pair(dx=0.25), down, 2)), (bumped, fresh(*changed, down, 2))):
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b)
    assert not np.array_equal(moved[1], again[1])
    for k in range(2 * P.RIMS_KEPT):
        P.rim_points(*pair(dx=0.01 * (k + 1)), down, 2)
    assert len(P._RIMS) == P.RIMS_KEPT


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


@pytest.mark.parametrize("periodic", [False, True])
def test_missing_neighbours_are_those_scipys_kd_tree_finds(periodic):
    """`_missing_neighbours`: a sample's neighbour one step away is missing where scipy's kd-tree
    (``cKDTree.query`` with its distance bound, on the wrapped parameters) finds no sample within
    1e-3 of the step, the same rows and parameters in the same order: samples on patch grids of
    two densities with holes, across a periodic seam, plus samples a hair (5e-4 and 2e-3 of the
    step) off a grid point."""
    from acra import hspline as H
    from acra import shapes
    from pipeline.spatial import cKDTree

    hs = H.from_grid(*(shapes.sphere(8, 8) if periodic else shapes.sheet(8, 8)[:1]), depth=2)
    rng = np.random.default_rng(3)
    pu, pv = hs.u.patches0, hs.v.patches0
    grid = np.stack(np.meshgrid(np.arange(0, pu, 1 / 8), np.arange(0, pv, 1 / 8), indexing="ij"), -1).reshape(-1, 2)
    uv = grid[rng.random(len(grid)) < 0.7]
    uv = np.concatenate([uv, [[pu - 0.125, 1.0], [0.0, 1.0], [0.0, 2.0]], uv[:20] + [[5e-4 / 8, 0.0]],
                         uv[20:40] + [[0.0, 2e-3 / 8]]])
    h = np.where(uv[:, 0] < 2.0, 1 / 8, 1 / 16)
    miss, n = P._missing_neighbours(hs, uv, h)
    src, hi = np.tile(np.arange(len(uv)), 4)[miss.reshape(-1)], n[miss]
    tree, want_src, want_hi = cKDTree(geometry.wrap_uv(hs, uv)), [], []
    for du, dv in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        n = uv + np.stack([du * h, dv * h], axis=1)
        ok = np.ones(len(n), bool)
        for c, d in enumerate((hs.u, hs.v)):
            if not d.periodic:
                ok &= (n[:, c] >= -1e-9) & (n[:, c] <= d.patches0 + 1e-9)
        dist, _ = tree.query(geometry.wrap_uv(hs, n), distance_upper_bound=2e-3 * h.max())
        miss = ok & (dist > 1e-3 * h)
        want_src.append(np.nonzero(miss)[0])
        want_hi.append(n[miss])
    np.testing.assert_array_equal(src, np.concatenate(want_src))
    np.testing.assert_array_equal(hi, np.concatenate(want_hi))
    assert 0 < len(src) < 4 * len(uv)


def test_a_box_pushed_along_an_axis_counts_every_rim_crossing_as_its_faces_would():
    """`_on_counted_faces`: a box's faces are all steep to a push along one of its axes or facing
    it, so every crossing counts without its face being found, as finding each face says (points
    on every side and face of the box); pushed at a slant, the faces are found and the slanted ones
    do not count."""
    import trimesh

    from pipeline.model import ColliderModel

    mesh = trimesh.creation.box(bounds=np.array([[-0.7, -0.9, -0.5], [0.9, 0.7, 0.5]]))
    shift = np.eye(4)
    shift[:3, 3] = [0.1, -0.05, 0.3]
    box = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/box", mesh.vertices, mesh.faces)), shift)
    rng = np.random.default_rng(5)
    tri = mesh.triangles[rng.integers(0, len(mesh.faces), 300)]
    points = np.einsum("ij,ijk->ik", rng.dirichlet([1.0, 1.0, 1.0], 300), tri) + shift[:3, 3]
    asked = []

    def at():
        asked.append(1)
        return points

    def by_faces(unit):
        face = box.static.index.query(points - shift[:3, 3])[2]
        nd = np.abs(geometry.world_normals(box, box.static.mesh.face_normals[face]) @ unit)
        return (nd <= P.RIM_STEEP) | (nd >= P.RIM_FACING)

    for unit in (np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0])):
        got = P._on_counted_faces(box, unit, len(points), at)
        np.testing.assert_array_equal(got, by_faces(unit))
        assert got.all() and not asked
    slant = np.array([0.0, 0.6, -0.8])  # |n·d| 0.6 on the ±y faces: neither steep nor facing
    got = P._on_counted_faces(box, slant, len(points), at)
    np.testing.assert_array_equal(got, by_faces(slant))
    assert asked and 0 < got.sum() < len(points)


def test_distinct_rows_are_distinct_by_their_bits():
    """`_distinct_rows`: one row of each distinct bit pattern (``-0.0`` apart from ``0.0``, a NaN
    row like itself), and each row's place among them gives back every row's bits."""
    rng = np.random.default_rng(11)
    base = np.round(rng.normal(size=(40, 2)) * 8) / 8
    base[3], base[4], base[5, 1] = [0.5, 0.0], [0.5, -0.0], np.nan
    x = base[rng.integers(0, len(base), 300)]
    first, at = P._distinct_rows(x)
    assert x[first][at].tobytes() == x.tobytes()
    assert len(first) == len({r.tobytes() for r in x}) == len({r.tobytes() for r in x[first]})
    assert [len(a) for a in P._distinct_rows(np.zeros((0, 2)))] == [0, 0]


def _rim_points_every_row(ga, gb, region_uv, direction, level):
    """`datapoints._rim_points` as arrays over every row of the region, repeats included: each
    crossing bisected and each sample cast once per row."""
    from acra import hspline as H
    from acra.targets import patch_groups
    from pipeline import detect as D
    from pipeline.model import apply_xform

    hs = ga.surface
    unit = direction / np.linalg.norm(direction)
    dens = geometry.patch_density(ga)
    pu = np.clip(np.floor(region_uv[:, 0]).astype(np.int64) % hs.u.patches0, 0, hs.u.patches0 - 1)
    pv = np.clip(np.floor(region_uv[:, 1]).astype(np.int64) % hs.v.patches0, 0, hs.v.patches0 - 1)
    miss, n = P._missing_neighbours(hs, region_uv, 1.0 / dens[pu, pv])
    src, hi = np.tile(np.arange(len(region_uv)), 4)[miss.reshape(-1)], n[miss]

    def world(uv):
        return apply_xform(ga.xform, H.evaluate(hs, *geometry.wrap_uv(hs, uv).T, det=ga.details).points)

    outside = ~D.inside(gb, world(hi))
    src, hi = src[outside], hi[outside]
    lo = region_uv[src]
    step = hi - lo
    for _ in range(P.RIM_BISECT):
        mid = 0.5 * (lo + hi)
        m_in = D.inside(gb, world(mid))[:, None]
        lo, hi = np.where(m_in, mid, lo), np.where(m_in, hi, mid)
    use = P._on_counted_faces(gb, unit, len(hi), lambda: world(hi))
    s_hit, hit = D.cast(gb, world(region_uv[src[use]]), np.broadcast_to(unit, (int(use.sum()), 3)))
    cross = geometry.wrap_uv(hs, (hi + step)[use][hit])
    mids, _, inv = patch_groups(hs, cross, level)
    g = len(mids)
    plane = np.stack([np.bincount(inv, s_hit[hit, c], g) for c in range(3)], axis=1)
    plane /= np.bincount(inv, minlength=g)[:, None]
    points = world(mids)
    ahead = (plane - points) @ unit
    keep = ahead > 0
    return mids[keep], points[keep], points[keep] + ahead[keep, None] * unit


@pytest.mark.parametrize("direction,turn", [((0.0, 0.0, -0.8), 0.0), ((0.1, -0.05, -1.0), 0.3)])
def test_rim_points_ask_each_distinct_crossing_once_with_every_rows_bits(monkeypatch, direction, turn):
    """`_rim_points` bisects each distinct sample's crossings and casts each sample once, every
    region row taking its sample's: the same bits as the arrays over every row
    (`_rim_points_every_row`) on a region whose samples on shared patch edges come twice, for
    fewer points asked; pushed along the box's axis and at a slant to a turned box (whose faces
    are found for each crossing)."""
    import trimesh

    from acra import hspline as H
    from acra import shapes
    from pipeline import detect as D
    from pipeline.model import ColliderModel

    cvs, _, _ = shapes.sheet(12, 12, width=4.0, depth=4.0)
    sheet = geometry.SurfaceGeometry(H.from_grid(cvs, depth=3), np.eye(4), "/sheet")
    mesh = trimesh.creation.box(bounds=np.array([[-0.7, -0.9, -0.5], [0.9, 0.7, 0.5]]))
    xform = trimesh.transformations.rotation_matrix(turn, [0.2, 0.3, 1.0])
    box = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/box", mesh.vertices, mesh.faces)), xform)
    region, _ = D.regions(sheet, box)
    uv = np.concatenate([region.uv, region.uv[::3]])  # samples given twice
    down = np.array(direction)
    asked, inside = [], D.inside
    monkeypatch.setattr(D, "inside", lambda g, p: asked.append(len(p)) or inside(g, p))
    got = P._rim_points(sheet, box, uv, down, 2)
    once = sum(asked)
    asked.clear()
    want = _rim_points_every_row(sheet, box, uv, down, 2)
    assert len(got[0]) >= 12 and once < sum(asked)
    for a, b in zip(got, want):
        assert a.tobytes() == b.tobytes()


def _bisected_in_turn(gb, world, lo, hi):
    """`_bisected` as the array form: `detect.inside` of the neighbours, then of each halving's
    midpoints in turn."""
    from pipeline import detect as D

    outside = ~D.inside(gb, world(hi))
    lo, hi = lo[outside], hi[outside]
    for _ in range(P.RIM_BISECT):
        mid = 0.5 * (lo + hi)
        m_in = D.inside(gb, world(mid))[:, None]
        lo, hi = np.where(m_in, mid, lo), np.where(m_in, hi, mid)
    return outside, hi


@pytest.mark.parametrize("paths,seed", [(P.RIM_PATHS, 0), (P.RIM_PATHS, 1), (0, 2)])
def test_bisected_asks_the_parity_once_with_the_answers_of_asking_in_turn(monkeypatch, paths, seed):
    """`_bisected` follows a segment whose point lies near the box's surface both ways and asks
    every near point's parity at the end: the same outside rows and crossings, bit for bit, as
    asking `detect.inside` in turn, for one parity call instead of one a round. Segments across
    the box's faces, edges and corners in the plane ``z = 0.1`` (the parameters are the points'
    x and y), their midpoints on a face, a rounding error or 1e-7 of the size off it at one
    halving or another, some neighbours inside or near; with no path to spare (``RIM_PATHS``
    0) each round asks its near points at once."""
    import trimesh

    from pipeline import detect as D
    from pipeline.model import ColliderModel

    monkeypatch.setattr(P, "RIM_PATHS", paths)
    mesh = trimesh.creation.box(bounds=np.array([[-0.5, -0.25, -0.5], [0.5, 0.75, 0.5]]))
    shift = np.eye(4)
    shift[:3, 3] = [0.125, -0.0625, 0.0]
    box = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/box", mesh.vertices, mesh.faces)), shift)
    rng = np.random.default_rng(seed)
    size = box.static.scale
    face = np.array([[0.625, 0.0], [-0.375, 0.0], [0.0, 0.6875], [0.0, -0.3125]])  # x = 0.625 (+x face), ...
    n = 400
    which = rng.integers(0, 4, n)
    along = rng.uniform(-0.3, 0.6, n)
    step = 2.0 ** -rng.integers(2, 6, n)
    # the face crossed at a halving's midpoint: lo and hi placed so that midpoint k lies on it
    k = rng.integers(0, P.RIM_BISECT + 1, n)
    off = rng.choice([0.0, 1e-16, 1e-7 * size, -1e-7 * size, 3e-3], n)
    lo, hi = np.empty((n, 2)), np.empty((n, 2))
    for i in range(n):
        axis, sign = (0 if which[i] < 2 else 1), (1.0 if which[i] in (0, 2) else -1.0)
        at = face[which[i], axis] + off[i]
        t = 1.0 - 2.0 ** -k[i]  # the k-th midpoint of [0, 1] always halving towards its outer end
        a = at - sign * t * step[i]
        lo[i, axis], hi[i, axis] = a, a + sign * step[i]
        lo[i, 1 - axis] = hi[i, 1 - axis] = along[i]
    lo[:20] = [0.125, 0.1875] + rng.uniform(-0.2, 0.2, (20, 2))  # neighbours inside
    hi[:20] = lo[:20] + rng.uniform(-0.05, 0.05, (20, 2))

    def world(uv):
        return np.column_stack([uv, np.full(len(uv), 0.1)])

    calls, parity = [], D._parity
    monkeypatch.setattr(D, "_parity", lambda s, p: calls.append(len(p)) or parity(s, p))
    got = P._bisected(box, world, lo, hi)
    ours = len(calls)
    calls.clear()
    want = _bisected_in_turn(box, world, lo, hi)
    assert got[0].tobytes() == want[0].tobytes() and got[1].tobytes() == want[1].tobytes()
    assert 0 < got[0].sum() < n - 20 + 1 and sum(calls) > 20  # near points at several halvings
    assert (ours == 1 if paths else ours == len(calls)) and len(calls) > 3
