"""`acra.float32.rounded` and `round_into` give numpy's float32 rounding bit for bit, and refuse NaN and inf."""

from __future__ import annotations

import numpy as np
import pytest

from acra import float32


def _cases() -> list[np.ndarray]:
    rng = np.random.default_rng(7)
    n = 30000
    every = rng.standard_normal(n) * 10.0 ** rng.integers(-50, 50, n)
    edges = np.array([0.0, -0.0, 1.0, -1.0, 0.1, 1e-46, 1.4e-45, 7e-46, 1.17549435e-38, 3.4028234663852886e38,
                      3.4028235677973366e38, 3.402823567797337e38, 1e39, -1e39, 1e300, 5e-324, 2.0**-149, 2.0**-150,
                      1 + 2.0**-24, 1 + 2.0**-24 + 2.0**-52, 1 + 3 * 2.0**-24, 16777217.0])
    return [every.reshape(-1, 3), edges.reshape(-1, 2), edges, np.asfortranarray(every.reshape(-1, 3)), np.zeros((0, 3))]


@pytest.mark.parametrize("k", range(5))
def test_rounded_is_numpys_float32_bit_for_bit(k):
    values = _cases()[k]
    got = float32.rounded(values)
    with np.errstate(over="ignore"):  # beyond the largest float32: infinity, as the kernel rounds
        want = values.astype(np.float32)
    assert got.shape == want.shape and got.dtype == np.float32 and got.flags.c_contiguous
    assert np.array_equal(got.view(np.uint32), np.ascontiguousarray(want).view(np.uint32))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_rounded_refuses_nan_and_inf(bad):
    values = np.ones((50, 3))
    values[37, 2] = bad
    assert float32.rounded(values) is None
    assert float32.rounded(values.astype(np.float32)) is None


def test_other_dtypes_are_numpys_and_one_specialisation_serves_read_only_and_writable():
    ints = np.arange(12, dtype=np.int64).reshape(4, 3)
    assert np.array_equal(float32.rounded(ints), ints.astype(np.float32))
    same = np.array([[1.5, 2.5, 3.5]], np.float32)
    assert np.array_equal(float32.rounded(same), same)
    shown = np.ones((3, 3))
    shown.flags.writeable = False
    assert np.array_equal(float32.rounded(shown), float32.rounded(np.ones((3, 3))))
    assert len(float32._rounded.signatures) == 1


@pytest.mark.parametrize("k", range(5))
def test_round_into_a_given_buffer_is_rounded(k):
    values = _cases()[k]
    out = np.full(values.shape, np.float32(7))
    assert float32.round_into(values, out)
    assert np.array_equal(out.view(np.uint32), float32.rounded(values).view(np.uint32))
    values = np.ascontiguousarray(values, dtype=np.float64).copy()
    if values.size:
        values.reshape(-1)[-1] = np.nan
        assert not float32.round_into(values, out)
