"""`acra.orientation`: the sign of a grid's enclosed volume, compiled, against the array form."""

import numpy as np

from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from acra.orientation import volume_sign, volume_sign_about_mean


def _array_form(pts, tris, centre):
    a, b, c = (pts[tris[:, i]] - centre for i in range(3))
    return 1 if np.einsum("ij,ij->i", a, np.cross(b, c)).sum() >= 0 else -1


def test_volume_sign_is_the_array_forms_where_sure():
    """Closed bumpy spheres either way round, far from the origin, and grids whose volume is
    (nearly) zero: a sure answer is the array form's sign; flat and empty grids are not sure."""
    rng = np.random.default_rng(5)
    sure = 0
    for trial in range(200):
        n = int(rng.integers(3, 20))
        u, v = np.meshgrid(np.linspace(0, 2 * np.pi, n + 1), np.linspace(0, np.pi, n + 1), indexing="ij")
        r = 1 + 0.3 * rng.normal(size=u.shape)
        pts = np.stack([r * np.cos(u) * np.sin(v), r * np.sin(u) * np.sin(v), r * np.cos(v)], -1).reshape(-1, 3)
        pts = pts * rng.choice([1e-3, 1.0, 1e3]) + rng.normal(size=3) * rng.choice([0.0, 1e3])
        q = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
        tris = np.concatenate([np.stack([q[:-1, :-1], q[1:, :-1], q[1:, 1:]], -1).reshape(-1, 3),
                               np.stack([q[:-1, :-1], q[1:, 1:], q[:-1, 1:]], -1).reshape(-1, 3)])
        if trial % 2:
            tris = tris[:, ::-1]
        if trial % 5 == 0:  # the grid and its mirror: volume about zero
            tris = np.concatenate([tris, tris[:, ::-1]])
        if trial % 7 == 0:
            pts[:, 2] = 0.0
        centre = pts.mean(axis=0)
        got = volume_sign(pts, tris, centre)
        if got:
            sure += 1
            assert got == _array_form(pts, tris, centre), trial
        if trial % 7 == 0:
            assert got == 0
    assert sure > 100
    assert volume_sign(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(3)) == 0


def _grid(rng, n):
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, n + 1), np.linspace(0, np.pi, n + 1), indexing="ij")
    r = 1 + 0.3 * rng.normal(size=u.shape)
    pts = np.stack([r * np.cos(u) * np.sin(v), r * np.sin(u) * np.sin(v), r * np.cos(v)], -1).reshape(-1, 3)
    q = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    tris = np.concatenate([np.stack([q[:-1, :-1], q[1:, :-1], q[1:, 1:]], -1).reshape(-1, 3),
                           np.stack([q[:-1, :-1], q[1:, 1:], q[:-1, 1:]], -1).reshape(-1, 3)])
    return pts, tris


def test_the_sign_about_the_mean_is_the_sign_about_numpys_mean():
    """`volume_sign_about_mean` gives ``points.mean(axis=0)``'s bits and `volume_sign` about
    it: bumpy spheres scaled over 16 decades with rows of every magnitude (where the order of
    the sum shows), shifted far off the origin, with a column of signed zeros, and tiny grids."""
    rng = np.random.default_rng(9)
    for trial in range(300):
        pts, tris = _grid(rng, int(rng.integers(1, 40)))
        pts = pts * 10.0 ** rng.integers(-8, 8, size=(len(pts), 1)) if trial % 3 == 0 else pts * rng.choice([1e-3, 1e3])
        pts = pts + rng.normal(size=3) * rng.choice([0.0, 1e3])
        if trial % 4 == 0:
            pts[:, 1] = -0.0
        if trial % 5 == 0:
            tris = tris[:, ::-1]
        sign, centre = volume_sign_about_mean(pts, tris)
        want = pts.mean(axis=0)
        np.testing.assert_array_equal(centre, want)
        assert np.array_equal(np.signbit(centre), np.signbit(want)), trial
        assert sign == volume_sign(pts, tris, want), trial


@settings(max_examples=200, deadline=None)
@given(hnp.arrays(np.float64, st.tuples(st.integers(1, 300), st.just(3)),
                  elements=st.floats(-1e12, 1e12, allow_nan=False, allow_subnormal=True)))
def test_the_mean_is_numpys_for_any_rows(pts):
    """The mean `volume_sign_about_mean` finds is ``points.mean(axis=0)`` bit for bit, for any
    finite rows (a single triangle over the first three rows, repeated where there are fewer)."""
    tris = np.array([[0, min(1, len(pts) - 1), min(2, len(pts) - 1)]], np.int64)
    sign, centre = volume_sign_about_mean(pts, tris)
    want = pts.mean(axis=0)
    assert np.array_equal(centre, want) and np.array_equal(np.signbit(centre), np.signbit(want))
    assert sign == volume_sign(pts, tris, want)


def test_the_sign_about_the_mean_of_no_triangles_is_not_sure():
    """No triangles: not sure (``0``), the mean still found; no points: a NaN mean, as numpy's."""
    sign, centre = volume_sign_about_mean(np.array([[1.0, 2.0, 3.0], [3.0, 2.0, 1.0]]), np.zeros((0, 3), np.int64))
    assert sign == 0 and np.array_equal(centre, [2.0, 2.0, 2.0])
    sign, centre = volume_sign_about_mean(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    assert sign == 0 and np.isnan(centre).all()
