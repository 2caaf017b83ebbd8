"""`pipeline.shape.Shape` of a responded surface: what the response's moved patches let it reuse."""

import numpy as np

from acra import hspline as H
from acra import respond as R
from acra.controls import check_controls
from acra.targets import DataPoints
from acra import shapes
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
    grids = S.patch_grids
    monkeypatch.setattr(S, "patch_grids", lambda surface, patches, *a, **k: seen.append(len(patches)) or grids(surface, patches, *a, **k))
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
