"""Contacts (`pipeline.contact`): the input motion rewound to the first touch, the depth along
the motion, the fallbacks without motion to rewind, grazing and coplanar contacts."""

import numpy as np
import pytest

from acra import hspline as H
from acra import shapes
from pipeline import geometry
from pipeline import contact as C
from pipeline import detect as D
from conftest import assert_finite, box, move, sheet_geom, sphere_geom


def jump_motion(sheet, collider):
    """Box above the sheet until t = 10, 70 % through it from t = 11 on, linear in between."""

    def geometry_at(t):
        z = 0.7 + (-0.2 - 0.7) * float(np.clip(t - 10.0, 0.0, 1.0))
        return sheet, geometry.ColliderGeometry(collider, move(0.3, 0.2, z))

    return geometry_at


def test_deep_jump_is_pushed_back_the_way_it_came():
    sheet, collider = sheet_geom(), box(0.5)
    geometry_at = jump_motion(sheet, collider)
    cache = C.RewindCache()
    results = {}
    for t in (11.0, 14.0):
        ga, gb = geometry_at(t)
        c = C.detect_pair(ga, gb, t, geometry_at, start=0.0, cache=cache)
        assert c is not None and c.rewound and c.region_b.empty  # the open sheet has no inside
        # first touch when the bottom face (z = 0.2 - 0.9 (t - 10)) reaches the sheet
        assert 10.0 + 2.0 / 9.0 - 1e-12 <= c.t_contact <= 10.0 + 2.0 / 9.0 + 2.0**-12
        # the contact is on the box's bottom face, near its centre, the side it came from
        assert c.local_b[2] == pytest.approx(-0.5, abs=1e-9)
        assert np.abs(c.local_b[:2]).max() < 0.1
        np.testing.assert_allclose(c.point_a, [0.3 + c.local_b[0], 0.2 + c.local_b[1], 0.0], atol=1e-9)
        np.testing.assert_allclose(c.point_b, [0.3 + c.local_b[0], 0.2 + c.local_b[1], -0.7], atol=1e-9)
        # the sheet must move with the box's motion (-z), to its bottom face, not through it
        push = (c.point_b - c.point_a) / np.linalg.norm(c.point_b - c.point_a)
        assert push @ [0.0, 0.0, -1.0] > 1.0 - 1e-9
        hits, valid = D.cast(gb, c.region_a.points, np.broadcast_to(push, c.region_a.points.shape))
        assert valid.all()
        np.testing.assert_allclose(hits[:, 2], -0.7, atol=1e-9)
        assert np.all(hits[:, 2] < c.region_a.points[:, 2])
        results[t] = c
    assert results[11.0].t_contact == results[14.0].t_contact
    np.testing.assert_array_equal(results[11.0].local_b, results[14.0].local_b)
    assert len(cache.anchors) == 1  # frame 14 reused the search of frame 11
    # without rewinding, the deepest point's nearest face is the top one: it would push through
    c = C.detect_pair(*geometry_at(11.0), 11.0)
    assert not c.rewound and c.depth == pytest.approx(0.3, abs=1e-12)
    assert c.point_b[2] - c.point_a[2] == pytest.approx(0.3, abs=1e-12)


def test_a_box_through_up_to_its_far_face_is_deep_along_the_motion():
    """A box that went through the sheet until its top face lies on it (hard case 9b):
    depth 0 to the nearest face, but the motion since the first touch carried the sheet's contact
    point a whole box height behind the bottom face it came in by. The sheet's vertices on the top
    face join the region, and their casts along the push leave by the bottom face, not the top."""
    sheet, collider = sheet_geom(), box(0.5)

    def geometry_at(t):  # above until t = 10, top face on the sheet (z = -0.5) from t = 11 on
        return sheet, geometry.ColliderGeometry(collider, move(0.3, 0.2, 0.7 - 1.2 * float(np.clip(t - 10.0, 0.0, 1.0))))

    ga, gb = geometry_at(11.0)
    assert not C.detect_pair(ga, gb, 11.0).region_a.points.size  # unrewound: nothing inside
    c = C.detect_pair(ga, gb, 11.0, geometry_at, start=0.0)
    assert c.rewound and c.depth == 0.0 and c.local_b[2] == pytest.approx(-0.5, abs=1e-9)
    assert c.depth_along == pytest.approx(1.0, abs=1e-9) and c.penetration == c.depth_along
    assert len(c.region_a.points) == 64 and np.all(c.region_a.depth == 0.0)  # the 8 x 8 under the face
    np.testing.assert_allclose(c.region_a.points[:, 2], 0.0, atol=1e-12)
    hits, valid = D.cast(gb, c.region_a.points, np.broadcast_to(c.point_b - c.point_a, c.region_a.points.shape))
    inner = np.all(np.abs(c.region_a.points[:, :2] - [0.3, 0.2]) < 0.5 - 1e-6, axis=1)
    assert valid[inner].all() and inner.sum() == 64
    np.testing.assert_allclose(hits[inner, 2], -1.0, atol=1e-6)
    # the same box pressed only 0.3 in: the motion and the nearest face agree, nothing added
    c = C.detect_pair(*geometry_at(10.5), 10.5, geometry_at, start=0.0)
    assert c.depth_along == pytest.approx(c.depth, abs=1e-9) and np.all(c.region_a.depth > 0.0)


def test_collision_at_the_first_frame_falls_back_to_the_deepest_point():
    sheet, collider = sheet_geom(), box(0.5)
    geometry_at = jump_motion(sheet, collider)
    c = C.detect_pair(*geometry_at(11.0), 11.0, geometry_at, start=11.0)
    assert not c.rewound and c.t_contact == 11.0
    assert c.point_a[2] == pytest.approx(0.0, abs=1e-12) and c.point_b[2] == pytest.approx(0.3, abs=1e-12)


def test_the_whole_region_fallback_takes_the_way_out_it_needs_least():
    """A unit cube centred on a sheet (hard case 2c): every sheet vertex inside is
    nearer a side face than the top or bottom (0.5 away), so the deepest vertex's nearest way out
    is sideways, where the far side of the region must travel up to 1.0. The whole region leaves
    by the top or the bottom at 0.5. A 0.3 box inside a sphere leaves along one of its face
    normals (1.127 for its far corners) rather than through a corner (1.26)."""
    sheet = geometry.SurfaceGeometry(H.from_grid(*shapes.sheet(12, 12, width=4.0, depth=4.0)), move(), "/sheet")
    cube = geometry.ColliderGeometry(box(0.5), move(0.1, -0.1, 0.0))
    near = C.detect_pair(sheet, cube)
    assert abs(near.point_b[2] - near.point_a[2]) < 1e-12  # the old rule: a side face
    c = C.detect_pair(sheet, cube, whole=True)
    assert not c.rewound and c.region_a.max_depth < 0.5 - 1e-3
    push = c.point_b - c.point_a
    np.testing.assert_allclose(np.abs(push), [0.0, 0.0, 0.5], atol=1e-12)
    assert np.all(np.abs(c.point_a[:2] - [0.1, -0.1]) < 0.1)  # central among the tied vertices
    assert C.detect_pair(sheet, cube, whole=True).point_b.tolist() == c.point_b.tolist()  # deterministic
    s, inner = sphere_geom(), geometry.ColliderGeometry(box(0.15), move())
    c = C.detect_pair(s, inner, whole=True)
    push = (c.point_b - c.point_a) / np.linalg.norm(c.point_b - c.point_a)  # the sphere's wall moves in
    assert np.sort(np.abs(push))[-1] > 1.0 - 1e-9
    # a far corner's travel to the wall along an axis (the unit sphere's, tessellated: within 2e-3)
    assert np.linalg.norm(c.point_b - c.point_a) == pytest.approx(np.sqrt(1.0 - 2 * 0.15**2) + 0.15, abs=2e-3)


def test_two_spheres_rewound_to_the_poles_that_met():
    hs = H.from_grid(*shapes.sphere(16, 14))
    a = geometry.SurfaceGeometry(hs, move(), "/a")

    def geometry_at(t):  # B falls from z = 2.3 to 1.9 between frames 10 and 11
        return a, geometry.SurfaceGeometry(hs, move(0.0, 0.0, 2.3 - 0.4 * float(np.clip(t - 10.0, 0.0, 1.0))), "/b")

    c = C.detect_pair(*geometry_at(11.0), 11.0, geometry_at, start=0.0)
    assert c is not None and c.rewound and c.a == "/a" and c.b == "/b"
    # the pole vertices are the tessellations' extreme points: they meet when B's centre is at z = 2
    assert 10.75 <= c.t_contact <= 10.75 + 2.0**-12
    assert c.uv_a[1] == pytest.approx(11.0, abs=1e-3) and c.uv_b[1] == pytest.approx(0.0, abs=1e-3)
    np.testing.assert_allclose(c.point_a, [0.0, 0.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(c.point_b, [0.0, 0.0, 0.9], atol=1e-6)  # B's south pole, now 0.1 deep
    assert c.depth == pytest.approx(0.1, abs=1e-3) and not c.region_a.empty and not c.region_b.empty
    # A's inside points cast along P_A -> P_B reach B's surface below them
    hits, valid = D.cast(geometry_at(11.0)[1], c.region_a.points, np.broadcast_to(c.point_b - c.point_a, c.region_a.points.shape))
    assert valid.all() and np.all(hits[:, 2] < c.region_a.points[:, 2])


@pytest.mark.parametrize("rewind", [False, True])
def test_grazing_contact(rewind):
    s, collider = sphere_geom(), box(1.0)
    depth = 1e-6 * 2.0  # of the sphere's diameter

    def geometry_at(t):
        z = 3.0 + (2.0 - depth - 3.0) * float(np.clip(t - 10.0, 0.0, 1.0))
        return s, geometry.ColliderGeometry(collider, move(0.0, 0.0, z))

    c = C.detect_pair(*geometry_at(11.0), 11.0, geometry_at if rewind else None, start=0.0)
    assert c is not None  # the pole vertex is exactly at z = 1
    assert_finite(c)
    assert c.depth == pytest.approx(depth, abs=1e-12)
    np.testing.assert_allclose(c.point_a, [0.0, 0.0, 1.0], atol=1e-9)
    if rewind:
        assert c.rewound and 11.0 - 2.0**-12 <= c.t_contact <= 11.0
        assert abs(c.local_b[2] + 1.0) < 1e-9
    else:
        assert c.point_b[2] == pytest.approx(1.0 - depth, abs=1e-12)


@pytest.mark.parametrize("rewind", [False, True])
def test_coplanar_face_on_the_sheet_gives_finite_output(rewind):
    sheet, collider = sheet_geom(), box(0.5)
    gb = geometry.ColliderGeometry(collider, move(0.3, 0.2, 0.5))  # bottom face lies on the sheet
    assert D.touching(sheet, gb)
    c = C.detect_pair(sheet, gb, 5.0, (lambda t: (sheet, gb)) if rewind else None, start=0.0)
    assert c is not None and not c.rewound  # always touching: no earlier free time
    assert_finite(c)
    assert c.depth <= 1e-12 and c.intersections.count > 0
    assert abs(c.point_a[2]) < 1e-12 and abs(c.point_b[2]) < 1e-12


def _turning_sheet(turn_per_frame: float, sink_per_frame: float):
    """A 7-unit sheet that turns about z by ``turn_per_frame`` radians a frame from t = 10 and a
    box (half size 0.5) over (1.5, 0) whose bottom face, 0.01 above the sheet at t = 9, sinks
    ``sink_per_frame`` a frame."""
    hs = H.from_grid(*shapes.sheet(10, 10, width=7.0, depth=7.0))
    collider = box(0.5)

    def geometry_at(t):
        a = turn_per_frame * max(t - 10.0, 0.0)
        turn = np.eye(4)
        turn[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
        z = 0.5 + 0.01 - sink_per_frame * (t - 9.0)
        return geometry.SurfaceGeometry(hs, turn, "/sheet"), geometry.ColliderGeometry(collider, move(1.5, 0.0, z))

    return geometry_at


def test_a_contact_that_slides_along_the_sheet_pushes_along_the_press():
    """The sheet turns 0.1 rad a frame under a box that sinks 0.05 a frame, first touching at
    t = 9.2: by t = 12 the sheet's first-touch point has turned about 0.3 along the sheet (0.2 rad
    on a circle of radius ~1.5) while the box went 0.14 in. That slide is the sheet's own motion along itself: `PairContact.slide` takes it
    out of ``P_B - P_A``, so the push is the press alone, straight down by the depth along."""
    geometry_at = _turning_sheet(0.1, 0.05)
    c = C.detect_pair(*geometry_at(12.0), 12.0, geometry_at, start=0.0)
    assert c is not None and c.rewound
    assert np.linalg.norm((c.point_b - c.point_a)[:2]) > 0.25
    assert abs(c.slide[2]) < 1e-12 and np.linalg.norm(c.slide) > 2.0 * c.depth_along
    np.testing.assert_allclose(c.push, [0.0, 0.0, -c.depth_along], atol=1e-9)
    assert c.depth_along == pytest.approx(0.05 * 3.0 - 0.01, abs=1e-12)  # the bottom face 0.14 under the sheet


def test_a_contact_that_goes_in_farther_than_it_slides_keeps_the_first_touch_pair():
    """The same sheet turning 0.01 rad a frame under a box sinking 0.1: the slide (about 0.03) is
    less than the press (about 0.2), so the first-touch points are paired as they are (slide
    exactly 0, push exactly ``P_B - P_A``)."""
    geometry_at = _turning_sheet(0.01, 0.1)
    c = C.detect_pair(*geometry_at(12.0), 12.0, geometry_at, start=0.0)
    assert c is not None and c.rewound and c.depth_along > 0.1
    assert not np.any(c.slide)
    np.testing.assert_array_equal(c.push, c.point_b - c.point_a)


def test_anchor_points_and_normals_evaluate_a_surface_once_for_every_matrix(monkeypatch):
    """`_point_at`, `_normal_at` and `_outward` of one surface at new matrices (a moving input's
    every frame) map the object-space point and normal evaluated at the first, with the bits of
    an evaluation at each matrix."""
    hs = H.from_grid(*shapes.sphere(16, 14))
    uv = np.array([1.25, 2.5])
    first = geometry.SurfaceGeometry(hs, move(0.5, 0.0, 0.0), "/s")
    C._point_at(first, uv), C._normal_at(first, uv), C._outward(first, uv, None)
    calls = []
    for name in ("evaluate", "surface_normals"):
        monkeypatch.setattr(H, name, (lambda f: lambda *a, **k: calls.append(f) or f(*a, **k))(getattr(H, name)))
    rot = np.eye(4)
    rot[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    rot[:3, 3] = (0.1, 0.2, 0.3)
    moved = geometry.SurfaceGeometry(hs, rot, "/s")
    p, n, out = C._point_at(moved, uv), C._normal_at(moved, uv), C._outward(moved, uv, None)
    assert not calls  # no evaluation at the new matrix
    monkeypatch.undo()
    u = uv.reshape(1, 2)
    obj_n = H.surface_normals(hs, u[:, 0], u[:, 1], det=moved.details)[1]
    np.testing.assert_array_equal(p, geometry.surface_points(moved, uv).points[0])
    np.testing.assert_array_equal(n, geometry.world_normals(moved, obj_n)[0])
    np.testing.assert_array_equal(out, geometry.world_normals(moved, moved.shape.outward * obj_n[0])[0])


def test_anchor_points_and_normals_are_kept_by_content_and_never_served_for_other_content():
    """`contact._point_at`, `_normal_at` and `_outward` keep their answers by the geometry's
    content and the material point: a new geometry with the same surface and matrix gets the
    kept answer, a moved matrix or changed CVs the answer of the new geometry, and at most
    `AT_KEPT` answers are kept."""
    hs = H.from_grid(*shapes.sphere(16, 14))
    uv = np.array([1.25, 2.5])
    g = geometry.SurfaceGeometry(hs, move(0.5, 0.0, 0.0), "/s")
    p, n, out = C._point_at(g, uv), C._normal_at(g, uv), C._outward(g, uv, None)
    same = geometry.SurfaceGeometry(H.with_cvs(hs, hs.cvs.copy()), move(0.5, 0.0, 0.0), "/s")
    assert C._point_at(same, uv) is p and C._normal_at(same, uv) is n and C._outward(same, uv, None) is out
    rot = np.eye(4)
    rot[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    for other in (geometry.SurfaceGeometry(hs, rot, "/s"), geometry.SurfaceGeometry(H.with_cvs(hs, 2.0 * hs.cvs), move(0.5, 0.0, 0.0), "/s")):
        np.testing.assert_array_equal(C._point_at(other, uv), geometry.surface_points(other, uv).points[0])
        ev = geometry.surface_points(other, uv, order=1)
        cross = np.cross(ev.du[0], ev.dv[0])
        np.testing.assert_allclose(C._normal_at(other, uv), cross / np.linalg.norm(cross), atol=1e-12)
        np.testing.assert_allclose(C._outward(other, uv, None), other.shape.outward * cross / np.linalg.norm(cross), atol=1e-12)
        assert not np.allclose(C._point_at(other, uv), p)
    b = box(0.5)
    local = np.array([0.5, 0.1, 0.2])  # on the box's +x face
    np.testing.assert_allclose(C._outward(geometry.ColliderGeometry(b, move()), None, local), [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(C._outward(geometry.ColliderGeometry(b, rot), None, local), [0.0, 1.0, 0.0], atol=1e-12)
    for k in range(2 * C.AT_KEPT):
        C._point_at(g, np.array([0.1 * k, 0.5]))
    assert len(C._AT) == C.AT_KEPT
    with pytest.raises(ValueError):
        p[0] = 0.0  # shared answers are read-only
