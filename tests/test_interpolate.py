"""Bartels–Beatty interpolation, its multi-point blend and the direct minimum-norm solve (§4.1)."""

import numpy as np
import pytest
from hypothesis import example, given, settings, strategies as st

from acra import hspline as H
from acra import shapes
from acra.basis import basis, locate, Direction
from acra.interpolate import (
    PointWeights, SystemTooLarge, bartels_beatty, blend_update, dense_bytes, iterate_blend, min_norm_solve, point_weights,
)


def curve_weights(n_cvs, params):
    """PointWeights of points on an open uniform cubic curve with ``n_cvs`` CVs."""
    d = Direction(n_cvs, False)
    seg, t = locate(d, np.asarray(params, float), 0)
    b = basis(t)
    point = np.repeat(np.arange(len(params)), 4)
    col = (seg[:, None] + np.arange(4)).reshape(-1)
    return PointWeights(0, point, col, b.reshape(-1), np.arange(n_cvs), len(params), np.ones(len(params), bool))


def test_one_point_on_a_curve_is_exact_and_minimal():
    rng = np.random.default_rng(0)
    rng.normal(size=(8, 3))  # keeps the seeded sequence the cases below draw from
    for u in rng.uniform(0, 5, 20):
        seg, t = locate(Direction(8, False), np.array([u]), 0)
        w = basis(t)[0]
        dq = rng.normal(size=3)
        dv = bartels_beatty(w, dq)
        assert np.abs(w @ dv - dq).max() <= 1e-12
        # minimum norm: equals the pseudo-inverse solution
        np.testing.assert_allclose(dv, np.linalg.pinv(w[None, :]) @ dq[None, :], atol=1e-12)


def test_one_point_on_a_surface_by_every_solver():
    hs = H.from_grid(*shapes.sheet(11, 11), depth=1)
    pw = point_weights(hs, 0, np.array([3.37]), np.array([5.81]))
    dq = np.array([[0.1, -0.2, 0.3]])
    for dv in (min_norm_solve(pw, dq), blend_update(pw, dq), iterate_blend(pw, dq, 1)[0]):
        assert np.abs(pw.apply(dv) - dq).max() <= 1e-12
    # the blend for one point is exactly Bartels-Beatty (eq. 4.11)
    np.testing.assert_allclose(blend_update(pw, dq), bartels_beatty(pw.w, dq[0]), atol=1e-15)


def test_thesis_curve_8_cvs_through_4_points_residual_falls():
    pw = curve_weights(8, [0.4, 1.3, 2.2, 4.1])
    rng = np.random.default_rng(1)
    dq = rng.normal(size=(4, 3))
    _, hist = iterate_blend(pw, dq, iterations=8)
    assert np.all(np.diff(hist) < 0), hist
    assert hist[5] < 0.2 * hist[0]
    assert np.abs(pw.apply(min_norm_solve(pw, dq)) - dq).max() <= 1e-10


def test_thesis_surface_11x11_through_3_points_residual_falls():
    hs = H.from_grid(*shapes.sheet(11, 11), depth=1)
    pw = point_weights(hs, 0, np.array([2.2, 2.9, 3.4]), np.array([3.1, 3.3, 2.6]))
    dq = np.array([[0, 0, 0.3], [0, 0, -0.2], [0.05, 0, 0.25]])
    _, hist = iterate_blend(pw, dq, iterations=8)
    assert np.all(np.diff(hist) < 0), hist
    assert np.abs(pw.apply(min_norm_solve(pw, dq)) - dq).max() <= 1e-10


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 12), st.integers(0, 10_000))
@example(8, 160)
def test_min_norm_is_exact_and_minimal_for_random_points(k, seed):
    rng = np.random.default_rng(seed)
    hs = H.from_grid(*shapes.sheet(9, 9), depth=1)
    pw = point_weights(hs, 0, rng.uniform(0, 6, k), rng.uniform(0, 6, k))
    dq = rng.normal(size=(k, 3))
    dv = min_norm_solve(pw, dq)
    W = pw.dense()
    lam = np.linalg.eigvalsh(W @ W.T)
    full = np.linalg.pinv(W) @ dq
    if lam[0] > 1e-4 * lam[-1]:  # distinct enough points (min_norm_solve's rcond): exact, = pinv
        assert np.abs(W @ dv - dq).max() <= 1e-8
        np.testing.assert_allclose(dv, full, atol=1e-7)
    else:  # nearly dependent (hypothesis found k=8, seed=160, full rank by matrix_rank): the
        # modes below rcond are dropped, so the moves are smaller than pinv's and in W's row space
        assert np.linalg.norm(dv) <= np.linalg.norm(full) * (1 + 1e-9)
        np.testing.assert_allclose(np.linalg.pinv(W) @ (W @ dv), dv, atol=1e-7)
    assert np.all(np.isfinite(dv))


def test_a_direct_solve_over_its_memory_bound_is_refused_before_it_allocates():
    rng = np.random.default_rng(3)
    hs = H.from_grid(*shapes.sheet(9, 9), depth=1)
    pw = point_weights(hs, 0, rng.uniform(0, 6, 5), rng.uniform(0, 6, 5))
    dq = rng.normal(size=(5, 3))
    k, p = 5, pw.cv_rows.size
    assert dense_bytes(k, p) == 8 * (2 * k * p + 3 * k * k)
    with pytest.raises(SystemTooLarge) as err:
        min_norm_solve(pw, dq, max_bytes=dense_bytes(k, p) - 1)
    assert (err.value.points, err.value.cvs, err.value.nbytes) == (k, p, dense_bytes(k, p))
    # at the bound the solve runs and is the unbounded one, bit for bit
    np.testing.assert_array_equal(min_norm_solve(pw, dq, max_bytes=dense_bytes(k, p)), min_norm_solve(pw, dq))


def test_coincident_points_with_different_targets_stay_finite():
    hs = H.from_grid(*shapes.sheet(8, 8), depth=1)
    pw = point_weights(hs, 0, np.array([2.5, 2.5]), np.array([2.5, 2.5]))
    dv = min_norm_solve(pw, np.array([[0, 0, 1.0], [0, 0, -1.0]]))
    assert np.all(np.isfinite(dv)) and np.abs(pw.apply(dv)).max() < 1e-6


def test_amplify_drops_a_weak_mode_only_where_it_fits_disagreement():
    """Two points 0.02 apart (relative Gram eigenvalue 1.8e-4): asks that agree to 1% are fitted
    exactly, the weak mode moving the CVs little; asks of 0.01 and 0 swing the exact fit's CVs 41
    times the ask, and ``amplify`` drops that mode: both points move the mean, CVs half the ask."""
    hs = H.from_grid(*shapes.sheet(8, 8), depth=1)
    pw = point_weights(hs, 0, np.array([2.5, 2.52]), np.array([2.5, 2.5]))
    near = np.array([[0, 0, 0.01], [0, 0, 0.0099]])
    np.testing.assert_array_equal(min_norm_solve(pw, near, amplify=2.0), min_norm_solve(pw, near))
    assert np.abs(pw.apply(min_norm_solve(pw, near, amplify=2.0)) - near).max() <= 1e-12
    apart = np.array([[0, 0, 0.01], [0, 0, 0.0]])
    assert np.abs(min_norm_solve(pw, apart)).max() > 0.4
    dv = min_norm_solve(pw, apart, amplify=2.0)
    assert np.abs(dv).max() < 0.006
    np.testing.assert_allclose(pw.apply(dv)[:, 2], 0.005, atol=1e-6)


def test_a_point_on_a_pole_weighs_the_ring_all_around():
    """At a pole every u names the same point, so its row is the row averaged over u: each ring
    CV weighs its row's end weight (1/6, 4/6, 1/6) over the ring size, whatever u was given."""
    hs = H.from_grid(*shapes.sphere(8, 9), depth=3)
    P = float(hs.v.patches0)
    hs = H.refine(hs, 2, H.pole_patches(hs, 2, 1, 1))
    for level in (0, 2):
        rows = [point_weights(hs, level, np.array([u]), np.array([P])) for u in (0.0, 0.37, 5.9)]
        for pw in rows[1:]:
            np.testing.assert_array_equal(pw.cv_rows, rows[0].cv_rows)
            np.testing.assert_array_equal(pw.w, rows[0].w)
        pw = rows[0]
        keys, w = H.pole_ring(hs, level, 1, 1)
        assert pw.active[0] and pw.cv_rows.size == keys.size
        assert abs(pw.w.sum() - 1.0) <= 1e-15  # partition of unity
        np.testing.assert_allclose(np.sort(pw.w), np.sort(np.tile(w / keys.shape[0], keys.shape[0])), rtol=1e-15)
        # three points on the pole: each the one point's row, bit for bit
        many = point_weights(hs, level, np.array([0.0, 0.37, 5.9]), np.full(3, P))
        np.testing.assert_array_equal(many.cv_rows, pw.cv_rows)
        for i in range(3):
            assert many.w[many.point == i].tobytes() == pw.w.tobytes()
            np.testing.assert_array_equal(many.col[many.point == i], pw.col)
    # level 1's ring is not refined: a pole point gets no weights there (obey leaves it alone)
    assert not point_weights(hs, 1, np.array([0.3]), np.array([0.0])).active[0]


def test_dense_weights_add_repeated_entries_as_add_at_does():
    """`PointWeights.dense` (np.bincount) is np.add.at's matrix bit for bit: repeated
    (point, CV) entries, as a ring constraint's own and mean terms give, signed zeros."""
    rng = np.random.default_rng(7)
    for _ in range(50):
        K, P, e = int(rng.integers(1, 60)), int(rng.integers(1, 120)), int(rng.integers(0, 3000))
        point, col = rng.integers(0, K, e), rng.integers(0, P, e)
        w = rng.normal(size=e) * 10.0 ** rng.uniform(-10, 10, e)
        w[rng.random(e) < 0.1] = -0.0
        pw = PointWeights(1, point, col, w, np.arange(P), K, np.ones(K, bool))
        ref = np.zeros((K, P))
        np.add.at(ref, (point, col), w)
        assert pw.dense().tobytes() == ref.tobytes()


@pytest.mark.parametrize("periodic", [(False, False), (True, False), (True, True)])
@pytest.mark.parametrize("seed", range(3))
def test_compiled_entries_equal_the_array_form(periodic, seed):
    """`interpolate._entries` (compiled off the poles, `acra.levelkernels.point_entries`) gives
    `_entries_numpy`'s points, rows and weights bit for bit on every level: points on knots
    (zero weights), on patches not refined, beside CVs not movable, and on a sphere's poles."""
    from acra import interpolate as I

    rng = np.random.default_rng(seed)
    if periodic == (True, False):
        hs = H.from_grid(shapes.sphere(8, 7)[0], True, False, depth=4)
    else:
        hs = H.from_grid(rng.normal(size=(8, 7, 3)), *periodic, depth=4)
    for k in (1, 2, 3):
        n = hs.u.patches(k), hs.v.patches(k)
        hs = H.make_movable(hs, k, np.stack([rng.integers(0, n[0], 3), rng.integers(0, n[1], 3)], axis=1))
    m = 200
    u = rng.uniform(0, hs.u.patches0, m)
    v = rng.uniform(0, hs.v.patches0, m)
    u[:20] = np.round(u[:20] * 4) / 4  # on knots of levels 0-2
    v[20:40] = np.round(v[20:40] * 8) / 8
    v[40:50] = 0.0  # on the south end (a pole of the sphere)
    v[50:55] = hs.v.patches0
    for k in range(hs.depth):
        got, ref = I._entries(hs, k, u, v), I._entries_numpy(hs, k, u, v)
        for a, b in zip(got, ref):
            x, y = np.concatenate(a), np.concatenate(b)
            assert x.dtype == y.dtype and x.tobytes() == y.tobytes()


def test_weights_number_their_columns_with_the_poles_given_or_not():
    """`point_weights` (the entries and ``active`` in one compiled pass,
    `levelkernels.point_entries`, with each pole's ring from a per-level table) gives the array
    form's entries numbered as `np.unique` numbers them, ``active`` where a point has an entry,
    and the same with the points' poles given (`H.pole_of`) or not; a ring not wholly movable
    gives its pole's points no weights."""
    from acra import interpolate as I

    rng = np.random.default_rng(11)
    hs = H.from_grid(shapes.sphere(8, 7)[0], True, False, depth=3)
    hs = H.refine(hs, 2, H.pole_patches(hs, 2, 1, 0))  # level 2's south ring movable, level 1's not
    hs = H.make_movable(hs, 1, [[3, 3], [12, 1]])
    m = 120
    u = rng.uniform(0, hs.u.patches0, m)
    v = rng.uniform(0, hs.v.patches0, m)
    v[:6], v[6:9] = 0.0, hs.v.patches0  # on the poles, three of them in a row
    for k in range(hs.depth):
        pt, rows, w = (np.concatenate(a) for a in I._entries_numpy(hs, k, u, v))
        cv_rows, col = np.unique(rows, return_inverse=True)
        for pole in (None, H.pole_of(hs, u, v)):
            pw = I.point_weights(hs, k, u, v, pole)
            assert pw.point.tobytes() == pt.tobytes() and pw.w.tobytes() == w.tobytes()
            assert pw.cv_rows.tobytes() == cv_rows.tobytes() and pw.col.tobytes() == col.tobytes()
            np.testing.assert_array_equal(pw.active, np.bincount(pt, minlength=m) > 0)
            np.testing.assert_array_equal(I.point_active(hs, k, u, v, pole), pw.active)
    assert I.point_active(hs, 2, u, v)[:6].all() and not I.point_active(hs, 1, u, v)[:9].any()


def test_compiled_entries_locate_parameters_outside_the_domain_as_numpy():
    """`levelkernels.point_entries` takes each point's segment and basis itself (`basis.locate`,
    `basis.basis`): parameters past a periodic seam wrap, past an open end clamp, as numpy's."""
    from acra import interpolate as I

    rng = np.random.default_rng(7)
    hs = H.from_grid(shapes.sphere(8, 7)[0], True, False, depth=3)
    hs = H.make_movable(H.make_movable(hs, 1, [[3, 3], [12, 1]]), 2, [[7, 9], [30, 20]])
    m = 300
    u = rng.uniform(-2 * hs.u.patches0, 3 * hs.u.patches0, m)
    v = rng.uniform(-1.0, hs.v.patches0 + 1.0, m)
    u[:30] = np.round(u[:30] * 4) / 4
    for k in range(hs.depth):
        got, ref = I._entries(hs, k, u, v), I._entries_numpy(hs, k, u, v)
        for a, b in zip(got, ref):
            x, y = np.concatenate(a), np.concatenate(b)
            assert x.dtype == y.dtype and x.tobytes() == y.tobytes()


@pytest.mark.parametrize("k", [1, 2, 13, 60])
def test_eigh_without_numpys_wrapper_gives_its_bits(k):
    """The solve's eigen-decomposition calls numpy's LAPACK driver directly: the same bits as
    `np.linalg.eigh`, and a matrix with a NaN gets its answer too."""
    from acra.interpolate import _eigh
    rng = np.random.default_rng(k)
    W = rng.normal(size=(k, 3 * k + 4))
    G = W @ W.T
    lam, vec = _eigh(G)
    ref = np.linalg.eigh(G)
    assert lam.tobytes() == ref.eigenvalues.tobytes() and vec.tobytes() == ref.eigenvectors.tobytes()
    bad = G.copy()
    bad[0, 0] = np.nan
    try:
        want = np.linalg.eigh(bad)
    except np.linalg.LinAlgError:
        with pytest.raises(np.linalg.LinAlgError):
            _eigh(bad)
    else:
        got = _eigh(bad)
        assert got[0].tobytes() == want[0].tobytes() and got[1].tobytes() == want[1].tobytes()


def test_min_norm_solve_with_every_point_active_equals_a_selection():
    """Every point active: the solve takes the weights and moves as they are, with the bits of
    the rows selected."""
    hs = H.from_grid(*shapes.sphere(8, 8), depth=1)
    rng = np.random.default_rng(3)
    u, v = rng.uniform(1, 7, 9), rng.uniform(0, 8, 9)
    pw = point_weights(hs, 0, u, v)
    dq = rng.normal(size=(9, 3))
    W = pw.dense()
    lam, vec = np.linalg.eigh(W @ W.T)
    keep = lam > 1e-4 * lam[-1]
    ref = W.T @ (vec[:, keep] @ (vec[:, keep].T @ dq / lam[keep][:, None]))
    assert min_norm_solve(pw, dq).tobytes() == ref.tobytes()


def test_a_repeated_solve_reuses_its_decomposition_with_the_same_bits(monkeypatch):
    """A solve asked again with the same weights (a contact held still) takes the kept dense
    weights and eigen-decomposition (`interpolate._DECOMPOSED`) instead of decomposing again, and
    returns the same bits for any wanted moves; a weight one ulp off decomposes afresh. The store
    keeps the most recent solves within its count and bytes."""
    from acra import interpolate as I
    hs = H.from_grid(*shapes.sphere(8, 8), depth=1)
    rng = np.random.default_rng(4)
    u, v = rng.uniform(1, 7, 12), rng.uniform(0, 8, 12)
    pw = point_weights(hs, 0, u, v)
    I._DECOMPOSED.clear()
    calls = []
    eigh = I._eigh
    monkeypatch.setattr(I, "_eigh", lambda g: calls.append(g.shape) or eigh(g))
    dq1, dq2 = rng.normal(size=(12, 3)), rng.normal(size=(12, 3))
    first = min_norm_solve(pw, dq1)
    fresh = PointWeights(0, pw.point.copy(), pw.col.copy(), pw.w.copy(), pw.cv_rows, 12, pw.active.copy())
    again, other = min_norm_solve(fresh, dq1), min_norm_solve(fresh, dq2)
    assert len(calls) == 1 and first.tobytes() == again.tobytes()
    I._DECOMPOSED.clear()
    assert other.tobytes() == min_norm_solve(pw, dq2).tobytes() and len(calls) == 2
    w = pw.w.copy()
    w[3] = np.nextafter(w[3], 1.0)
    min_norm_solve(PointWeights(0, pw.point, pw.col, w, pw.cv_rows, 12, pw.active), dq1)
    assert len(calls) == 3
    for n in range(I._DECOMPOSED_KEEP + 5):  # the store keeps the most recent alone
        min_norm_solve(point_weights(hs, 0, u + 0.01 * n, v), dq1)
    assert len(I._DECOMPOSED) == I._DECOMPOSED_KEEP
    I._DECOMPOSED.clear()
    min_norm_solve(pw, dq1)
    size = next(iter(I._DECOMPOSED.values()))[3]  # the bytes the entry holds
    monkeypatch.setattr(I, "_DECOMPOSED_BYTES", 4 * size + size // 2)
    for n in range(6):  # and within its bytes: four solves of this size
        min_norm_solve(point_weights(hs, 0, u + 0.01 * n, v), dq1)
    assert len(I._DECOMPOSED) == 4
    monkeypatch.setattr(I, "_DECOMPOSED_BYTES", 4 * size - 1)  # one past a quarter of them is not kept
    I._DECOMPOSED.clear()
    min_norm_solve(pw, dq1)
    assert not I._DECOMPOSED


def test_point_active_agrees_with_the_weights_on_and_off_the_poles():
    """`point_active` tells a point on a pole by whether its ring is wholly movable, without
    gathering the ring: the same answer as the weights' ``active`` on every level."""
    from acra.interpolate import point_active
    hs = H.from_grid(*shapes.sphere(8, 9), depth=3)
    P = float(hs.v.patches0)
    hs = H.refine(hs, 2, H.pole_patches(hs, 2, 1, 1))  # level 2's north ring movable, level 1's not
    hs = H.refine(hs, 1, np.array([[2, 3], [3, 3]]))
    rng = np.random.default_rng(5)
    u = np.concatenate([rng.uniform(0, 8, 12), [0.3, 4.1, 2.0, 6.5]])
    v = np.concatenate([rng.uniform(0, P, 12), [0.0, P, P, 0.0]])
    for level in range(3):
        want = point_weights(hs, level, u, v).active
        np.testing.assert_array_equal(point_active(hs, level, u, v), want)
    assert point_active(hs, 2, u, v)[[13, 14]].all() and not point_active(hs, 1, u, v)[12:].any()
