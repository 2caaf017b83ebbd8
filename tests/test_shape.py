"""`pipeline.shape.Shape` of a responded surface: what the response's moved patches let it reuse."""

import numpy as np

from acra import hspline as H
from acra import respond as R
from acra.controls import check_controls
from acra.targets import DataPoints
from acra import shapes
from acra.tessellate import patch_grids
from pipeline import shape as S


def _responded():
    hs = H.from_grid(*shapes.sphere(10, 15), depth=4)
    a = np.zeros(4)
    a[2] = 1.0
    ctl = check_controls(4, a, np.ones(4), np.zeros(4), np.zeros(4), refine="refine")
    uv = np.array([[2.5, 6.5]])
    q = H.evaluate(hs, uv[:, 0], uv[:, 1]).points
    new, rep = R.respond(hs, DataPoints(uv, q + [0.0, 0.0, -0.05], np.array([True])), ctl, det=H.details(hs))
    return hs, new, rep


def test_a_responded_shape_evaluates_only_the_moved_patches_and_gives_the_same_bits(monkeypatch):
    hs, new, rep = _responded()
    parent = S.Shape(hs)
    parent._coarse, parent.closed  # noqa: B018  (the round's view asked the parent first)
    seen = []
    grids = S.coarse_points
    monkeypatch.setattr(S, "coarse_points", lambda surface, patches, *a, **k: seen.append(len(patches)) or grids(surface, patches, *a, **k))
    child = S.Shape(new)
    child.__dict__["details"] = rep.details
    child.parent, child.moved = parent, rep.moved
    pts, tris = child._coarse
    assert seen == [int(rep.moved.sum())] and seen[0] < rep.moved.size
    fresh = S.Shape(new)
    want_pts, want_tris = fresh._coarse
    assert pts.tobytes() == want_pts.tobytes() and np.array_equal(tris, want_tris)
    np.testing.assert_array_equal(child._stale, H.changed_patches(hs, new) | (parent.density_map != child.density_map))
    assert child.outward == fresh.outward


def test_a_responded_shape_takes_its_parents_closedness_where_no_end_patch_moved(monkeypatch):
    hs, new, rep = _responded()
    assert not (rep.moved[:, 0].any() or rep.moved[:, -1].any())  # the contact is off the poles
    parent = S.Shape(hs)
    assert parent.closed and S.Shape(new).closed
    child = S.Shape(new)
    child.parent, child.moved = parent, rep.moved
    monkeypatch.setattr(S.H, "evaluate", None)  # nothing to evaluate
    assert child.closed


def test_a_shape_without_moved_patches_compares_the_levels():
    hs, new, rep = _responded()
    child = S.Shape(new)
    child.parent = S.Shape(hs)
    np.testing.assert_array_equal(child._stale, H.changed_patches(hs, new) | (child.parent.density_map != child.density_map))
    assert "_stale" in child.__dict__ or child.moved is None


def _surfaces():
    """Seeded surfaces: a responded sphere with details (periodic in u, poles in v), a torus
    (periodic both ways) and an open sheet, their level-0 CVs jittered."""
    rng = np.random.default_rng(7)
    _, responded, _ = _responded()
    out = [responded]
    for made in (shapes.torus(8, 9), shapes.sheet(7, 6)):
        cvs, *periodic = made if isinstance(made, tuple) else (made,)
        cvs = np.asarray(cvs, np.float64) + rng.normal(0.0, 0.02, np.shape(cvs))
        out.append(H.from_grid(cvs, *periodic, depth=1))
    return rng, out


def test_coarse_points_and_triangles_are_patch_grids_bits():
    rng, surfaces = _surfaces()
    for hs in surfaces:
        det = H.details(hs) if hs.depth > 1 else None
        mask = np.ones((hs.u.patches0, hs.v.patches0), bool)
        for trial in range(6):
            chosen = mask if trial == 0 else rng.random(mask.shape) < rng.uniform(0.05, 0.9)
            p = np.argwhere(chosen)
            pts, _, tris, _ = patch_grids(hs, p, 2, det=det)
            assert S.coarse_points(hs, p, det).tobytes() == pts.tobytes()
            assert np.array_equal(S.coarse_triangles(len(p)), tris) and S.coarse_triangles(len(p)).dtype == np.int64


def test_a_shape_whose_every_patch_moved_evaluates_them_all_and_takes_its_parents_triangles():
    hs, new, rep = _responded()
    parent = S.Shape(hs)
    parent._coarse  # noqa: B018
    child = S.Shape(new)
    child.parent, child.moved = parent, np.ones_like(rep.moved)
    pts, tris = child._coarse
    want_pts, want_tris = S.Shape(new)._coarse
    assert pts.tobytes() == want_pts.tobytes() and np.array_equal(tris, want_tris)
    assert tris is parent._coarse[1]
    orphan = S.Shape(new)
    orphan.parent, orphan.moved = S.Shape(hs), np.ones_like(rep.moved)  # the parent's grid not built: its own triangles
    assert np.array_equal(orphan._coarse[1], want_tris) and "_coarse" not in orphan.parent.__dict__


def _big_hull():
    from scipy.spatial import ConvexHull

    cvs = shapes.sphere(64, 48, radii=(1.0, 0.85, 0.9))[0].reshape(-1, 3)
    index = S.HullIndex(ConvexHull(cvs))
    assert len(index.equations) > S.HullIndex.DIRECT
    return cvs, index


def test_a_large_hull_tests_a_small_boxs_points_against_the_facets_near_it():
    """`HullIndex.within` on a large hull (a 64x48 ellipsoid net's, about 4,500 facets) of points
    in a small box (a contact's) answers as the compiled test against every facet, bit for bit,
    at the slack `Shape.signed` uses, with no kd-tree of cone directions built: random
    boxes about the surface, points in them, CVs within 1e-10 and the CVs themselves."""
    from acra import halfspaces

    rng = np.random.default_rng(11)
    cvs, index = _big_hull()
    eq = index.equations
    for _ in range(40):
        centre = cvs[rng.integers(len(cvs))] * rng.uniform(0.9, 1.1)
        half = rng.uniform(0.001, 0.1, 3)
        q = rng.uniform(centre - half, centre + half, (int(rng.integers(1, 600)), 3))
        near = np.all(np.abs(cvs - centre) <= half, axis=1)
        q = np.concatenate([q, cvs[near], cvs[near] * (1 + rng.normal(size=(near.sum(), 1)) * 1e-10)])
        np.testing.assert_array_equal(index.within(q, 1e-9), halfspaces.within(eq, q, 1e-9))
    assert "_cones" not in index.__dict__
    q = np.array([[0.0, 0.0, 0.0], [0.1, 0.1, 0.1], [1.2, 0.0, 0.0]])
    np.testing.assert_array_equal(index.within(q, 1e-9), [True, True, False])


def test_a_large_hull_keeps_only_facets_whose_planes_pass_near_the_box():
    """`HullIndex._facets_near` of a box near the hull's side keeps the facets whose bound over
    the box reaches ``slack`` and drops every facet that holds the whole box: each dropped facet's
    value at the box's eight corners is below ``slack``; a box holding the whole hull keeps more
    than `DIRECT` facets (``None``: the cone lookup answers), and so does a non-finite point."""
    cvs, index = _big_hull()
    eq = index.equations
    q = cvs[[504, 505, 552]] * 0.99  # three CVs about the equator, moved in
    near = index._facets_near(q, 1e-9)
    assert near is not None and 0 < len(near) < 200
    lo, hi = q.min(axis=0), q.max(axis=0)
    corners = np.array([[(lo, hi)[b >> i & 1][i] for i in range(3)] for b in range(8)])
    dropped = np.setdiff1d(np.arange(len(eq)), near)
    assert (corners @ eq[dropped, :3].T + eq[dropped, 3]).max() < 1e-9
    assert index._facets_near(np.array([[-1.1, -1.0, -1.0], [1.1, 1.0, 1.0]]), 1e-9) is None
    assert index._facets_near(np.array([[np.nan, 0.0, 0.0], [0.1, 0.0, 0.0]]), 1e-9) is None


def _display(hs, det):
    """A display of ``hs`` as `outward_shown` reads one: its own adaptive topology at 8 samples
    and the points there."""
    from types import SimpleNamespace

    from acra.tessellate import grid_samples, run_topology

    topo = run_topology([hs], 8)
    return SimpleNamespace(surface=hs, topology=topo, points=grid_samples(hs, topo, det, normals=False)[0], details=det)


def test_a_responded_shape_reads_its_moved_coarse_samples_from_its_display(monkeypatch):
    hs, new, rep = _responded()
    torus = H.from_grid(*shapes.torus(8, 9))  # periodic both ways: both seams' end samples
    moved = H.from_grid(torus.cvs + np.random.default_rng(3).normal(0.0, 0.02, torus.cvs.shape), True, True)
    cases = [(hs, new, rep.details, rep.moved), (hs, new, rep.details, np.ones_like(rep.moved)),
             (torus, moved, None, np.ones((8, 9), bool))]
    for old, surface, det, patches in cases:
        want = S.Shape(surface)
        want.outward  # noqa: B018  (evaluated in full)
        parent = S.Shape(old)
        parent._coarse  # noqa: B018
        child = S.Shape(surface)
        child.__dict__["details"] = det
        child.parent, child.moved = parent, patches
        shown = _display(surface, det)
        with monkeypatch.context() as m:
            m.setattr(S, "coarse_points", None)  # nothing evaluated: every sample is a display vertex
            assert child.outward_shown(shown) == want.outward
        assert child._coarse[0].tobytes() == want._coarse[0].tobytes() and child._display is None
    other = S.Shape(new)  # a display evaluated with other details: the samples are evaluated
    other.__dict__["details"] = rep.details
    other.parent, other.moved = S.Shape(hs), rep.moved
    assert other.outward_shown(_display(new, H.details(new))) == S.Shape(new).outward
    assert other._coarse[0].tobytes() == S.Shape(new)._coarse[0].tobytes()
