"""Uniform cubic B-spline basis: exact identities of thesis §3.2 and binary subdivision."""

import numpy as np
import pytest
from hypothesis import given, strategies as st

from acra.basis import Direction, basis, basis_all, basis_rows, locate, refine_rows


@given(st.lists(st.floats(0.0, 1.0), min_size=1, max_size=50))
def test_partition_of_unity_and_non_negative(ts):
    b = basis(np.array(ts))
    assert np.all(b >= 0.0)
    np.testing.assert_allclose(b.sum(axis=1), 1.0, rtol=0, atol=1e-15)


def test_derivatives_sum_to_zero_and_match_closed_form():
    t = np.linspace(0, 1, 101)
    for order in (1, 2, 3):
        np.testing.assert_allclose(basis(t, order).sum(axis=1), 0.0, atol=1e-14)
    # B3 = t^3/6 and B0 = (1-t)^3/6 (thesis eq. 3.2)
    np.testing.assert_allclose(basis(t)[:, 3], t**3 / 6, atol=1e-16)
    np.testing.assert_allclose(basis(t, 1)[:, 0], -3 * (1 - t) ** 2 / 6, atol=1e-15)
    np.testing.assert_allclose(basis(t, 2)[:, 1], (18 * t - 12) / 6, atol=1e-14)


@given(st.lists(st.sampled_from([0.0, 1.0, 0.5, 0.125]) | st.floats(0.0, 1.0), min_size=1, max_size=40),
       st.integers(0, 3))
def test_basis_rows_equal_basis_all_bit_for_bit(ts, order):
    # one row takes BLAS's vector route, several rows its matrix route, which round differently
    # (a knot's derivative weight is 0.0 alone and 2.8e-17 among others): both must match
    t = np.array(ts)
    want = basis_all(t, order).transpose(1, 0, 2)
    got = basis_rows(t, order)
    assert got.shape == (len(ts), order + 1, 4) and got.tobytes() == np.ascontiguousarray(want).tobytes()


def test_knot_values_are_one_sixth_four_sixths():
    np.testing.assert_allclose(basis(np.array([0.0]))[0], [1 / 6, 4 / 6, 1 / 6, 0], atol=1e-16)
    np.testing.assert_allclose(basis(np.array([1.0]))[0], [0, 1 / 6, 4 / 6, 1 / 6], atol=1e-16)


def test_c2_joins_between_segments():
    # the last three functions of a segment at t=1 continue as the first three at t=0
    for order in range(3):
        left = basis(np.array([1.0]), order)[0]
        right = basis(np.array([0.0]), order)[0]
        np.testing.assert_allclose(left[1:], right[:3], atol=1e-14)


def _curve(cvs, d: Direction, level, x):
    seg, t = locate(d, x, level)
    idx = d.wrap_cv(seg[:, None] + np.arange(4), level)
    return np.einsum("ma,mac->mc", basis(t), cvs[idx])


@pytest.mark.parametrize("periodic,n", [(False, 4), (False, 9), (True, 3), (True, 7)])
def test_subdivision_reproduces_the_curve_exactly(periodic, n):
    rng = np.random.default_rng(n)
    d = Direction(n, periodic)
    cvs = rng.normal(size=(n, 3))
    fine_idx, fine_w = refine_rows(d, 0, np.arange(d.cvs(1)))
    fine = np.einsum("ma,mac->mc", fine_w, cvs[fine_idx])
    assert fine.shape[0] == d.cvs(1)
    x = rng.uniform(0, d.patches0, 10_000)
    np.testing.assert_allclose(_curve(fine, d, 1, x), _curve(cvs, d, 0, x), rtol=0, atol=1e-13)
    # and once more to level 2
    idx2, w2 = refine_rows(d, 1, np.arange(d.cvs(2)))
    fine2 = np.einsum("ma,mac->mc", w2, fine[idx2])
    np.testing.assert_allclose(_curve(fine2, d, 2, x), _curve(cvs, d, 0, x), rtol=0, atol=1e-13)


def test_direction_counts_and_errors():
    assert Direction(7, False).patches(2) == 16 and Direction(7, False).cvs(2) == 19
    assert Direction(5, True).patches(3) == 40 and Direction(5, True).cvs(3) == 40
    with pytest.raises(ValueError, match="open direction needs at least 4"):
        Direction(3, False)
    with pytest.raises(ValueError, match="periodic direction needs at least 3"):
        Direction(2, True)


def test_locate_clamps_open_and_wraps_periodic():
    seg, t = locate(Direction(6, False), np.array([-1.0, 0.0, 2.5, 3.0, 4.0]), 0)
    np.testing.assert_array_equal(seg, [0, 0, 2, 2, 2])
    np.testing.assert_allclose(t, [0, 0, 0.5, 1, 1])
    seg, t = locate(Direction(4, True), np.array([-0.5, 4.25]), 1)
    np.testing.assert_array_equal(seg, [7, 0])
    np.testing.assert_allclose(t, [0, 0.5])
