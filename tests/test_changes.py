"""`acra.changes`: where two H-splines of one grid differ."""

import numpy as np
import pytest

from acra import changes
from acra import hspline as H
from acra import shapes
from conftest import nudged, wavy_sheet, with_random_offsets


def _surfaces(seed: int, open_: bool):
    """A surface with offsets on every fine level (an open sheet or a closed sphere)."""
    if open_:
        hs = wavy_sheet()
        for k, cv in ((1, [3, 3]), (2, [5, 5]), (3, [10, 9])):
            hs = H.make_movable(hs, k, [cv])
        return with_random_offsets(hs, 0.05, seed)
    hs = H.from_grid(*shapes.sphere(12, 10), depth=4)
    for k in (1, 2, 3):
        hs = H.make_movable(hs, k, [[1 << (k - 1), 4 << k]])
    return with_random_offsets(hs, 0.02, seed)


@pytest.mark.parametrize("seed,open_", [(0, True), (1, False), (2, True), (3, False)])
@pytest.mark.parametrize("level", [0, 1, 2, 3])
def test_first_moved_and_moved_cvs_name_the_level_and_the_cvs_a_move_changed(seed, open_, level):
    rng = np.random.default_rng(seed)
    hs = _surfaces(seed, open_)
    moved = nudged(hs, level, rng)
    assert changes.first_moved(hs, moved) == level
    assert changes.first_moved(hs, hs) == hs.depth
    for k in range(1, hs.depth):
        a, b = hs.level(k), moved.level(k)
        assert np.array_equal(a.cv_keys, b.cv_keys)
        want = np.any(a.offsets != b.offsets, axis=-1)
        np.testing.assert_array_equal(changes.moved_cvs(hs, moved, k), want)
        assert want.sum() == (1 if k == level else 0)


def test_a_refinement_alone_moves_nothing():
    """New CVs with zero offsets reproduce the surface: no level moved, no patch changed."""
    hs = _surfaces(0, True)
    finer = H.make_movable(hs, 2, [[12, 9]])
    assert changes.first_moved(hs, finer) == hs.depth
    assert not changes.changed_patches(hs, finer).any()
    assert not changes.moved_cvs(hs, finer, 2).any()


@pytest.mark.parametrize("seed,open_", [(4, True), (5, False), (6, True), (7, False)])
@pytest.mark.parametrize("level", [0, 1, 2, 3])
def test_changed_patches_hold_every_point_whose_evaluation_changed(seed, open_, level):
    """Every sample point whose evaluated position or normal changed lies on a level-0 patch
    `changed_patches` marks (its margin covers the finer details whose frames follow the move)."""
    rng = np.random.default_rng(seed)
    hs = _surfaces(seed, open_)
    moved = nudged(hs, level, rng)
    mask = changes.changed_patches(hs, moved)
    u, v = (np.linspace(0.0, d.patches0, 8 * d.patches0, endpoint=False) + 1.0 / 16 for d in (hs.u, hs.v))
    uu, vv = (a.ravel() for a in np.meshgrid(u, v, indexing="ij"))
    a = H.evaluate(hs, uu, vv, det=H.details(hs))
    b = H.evaluate(moved, uu, vv, det=H.details(moved))
    differ = np.any(a.points != b.points, axis=1)
    assert differ.any()
    pu, pv = np.floor(uu).astype(int), np.floor(vv).astype(int)
    assert mask[pu[differ], pv[differ]].all()
    if level == 3:  # a finest-level move is local: it marks part of the surface
        assert not mask.all()


def test_grown_patches_wrap_a_periodic_direction_and_clip_an_open_one():
    hs = H.from_grid(*shapes.sphere(12, 10), depth=2)  # periodic in one direction, open in the other
    periodic = 0 if hs.u.periodic else 1
    mask = np.zeros((hs.u.patches0, hs.v.patches0), bool)
    mask[0, 0] = True
    grown = changes.grown_patches(hs, mask, 2)
    want = np.zeros_like(mask)
    rows = [0, 1, 2, -1, -2]
    lo = [0, 1, 2]
    if periodic == 0:
        want[np.ix_(rows, lo)] = True
    else:
        want[np.ix_(lo, rows)] = True
    np.testing.assert_array_equal(grown, want)
    assert changes.grown_patches(hs, mask, 0) is mask


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("level", [1, 2, 3])
def test_mark_moved_marks_changed_patches_of_a_one_level_move_before_its_margin(seed, level):
    rng = np.random.default_rng(seed)
    hs = _surfaces(seed, bool(seed % 2))
    moved = nudged(hs, level, rng)
    stale = np.zeros((hs.u.patches0, hs.v.patches0), bool)
    changes.mark_moved(hs, moved, level, stale)
    np.testing.assert_array_equal(stale, changes.changed_patches(hs, moved, margin=0, levels=(level,)))
    assert stale.any()


def test_bits_tell_a_signed_zero_from_zero():
    x = np.array([[0.0, -0.0, 1.0]])
    b = changes.bits(x)
    assert b.dtype == np.int64 and b[0, 0] != b[0, 1] and b[0, 2] == np.float64(1.0).view(np.int64)
