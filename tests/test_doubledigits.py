"""`acra.doubledigits` finds each float64's shortest round-trip digits, the closest where several
are as short, as USD's ``.usda`` writer prints them: held to Python's ``repr`` (David Gay's
shortest digits, ties to even) and, through `acra.floattext`, to USD's text byte for byte."""

from __future__ import annotations

from decimal import Decimal

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from acra import doubledigits, floattext
from acra.doubledigits import shortest_digits64
from pipeline.output_layer import _float_texts

from conftest import usd_array_text


def repr_digits(x: float) -> tuple[int, int]:
    """``(c, k)`` with ``|x| = c 10^k``, ``c`` free of trailing zeros, from ``repr(x)``."""
    t = Decimal(repr(abs(float(x)))).normalize().as_tuple()
    return int("".join(map(str, t.digits))), t.exponent


def _mismatches(values: np.ndarray) -> list:
    cs, ks, status = shortest_digits64(np.ascontiguousarray(values, dtype=np.float64).view(np.uint64))
    return [x for x, c, k, s in zip(values, cs, ks, status) if s != 0 or (int(c), int(k)) != repr_digits(x)]


def test_random_bits_of_every_exponent_give_repr_s_digits():
    rng = np.random.default_rng(41)
    n = 60_000
    exps = rng.integers(0, 0x7FF, n).astype(np.uint64)  # every biased exponent but inf / NaN's, subnormals too
    bits = (exps << np.uint64(52)) | rng.integers(0, 2**52, n, dtype=np.int64).astype(np.uint64)
    values = bits.view(np.float64)
    assert _mismatches(values[values != 0]) == []


def test_edges_powers_and_short_values_give_repr_s_digits():
    """Powers of two (the interval's lower end at half the distance) and of ten, their
    neighbours, the subnormal and normal ends, integers, dyadic values and few-digit decimals
    (where the scaled ends are exact and a dropped 5 can be a tie)."""
    rng = np.random.default_rng(43)
    n = 20_000
    special = np.array([5e-324, 1e-323, 2.2250738585072014e-308, 2.225073858507201e-308, 1.7976931348623157e308, 0.1, 1 / 3, 1e15, 1e16,
                        1e22, 1e23, 2.0**53 + 2, 123456789012345680.0]
                       + [2.0**i for i in range(-1074, 1024)] + [10.0**i for i in range(-323, 309)])
    above = np.nextafter(special[special < special.max()], np.inf)
    values = np.concatenate([special, above, np.nextafter(special, 0),
                             rng.integers(1, 10**17, n).astype(np.float64),
                             rng.integers(1, 2**20, n) / 2.0 ** rng.integers(0, 80, n),
                             rng.integers(1, 10**6, n) / 10.0 ** rng.integers(0, 25, n),
                             rng.integers(1, 10**6, n) * 10.0 ** rng.integers(0, 300, n),
                             rng.standard_normal(n).astype(np.float32).astype(np.float64)])
    assert _mismatches(values[values != 0]) == []


@njit
def _ryu_digits(bits):
    """`doubledigits._d2s`'s digits of each nonzero finite float64 ``bits (n,) uint64``."""
    cs = np.zeros(bits.shape[0], np.int64)
    ks = np.zeros(bits.shape[0], np.int64)
    for i in range(bits.shape[0]):
        cs[i], ks[i] = doubledigits._d2s(np.int64(bits[i]) & 0x7FFFFFFFFFFFFFFF)
    return cs, ks


def exact_digits(bits):
    """`doubledigits._exact` of each nonzero finite float64 ``bits (n,) uint64``: ``(c, k,
    status)``, status 2 where the exact decimal has more than 14 digits."""
    cs = np.zeros(bits.shape[0], np.int64)
    ks = np.zeros(bits.shape[0], np.int64)
    st = np.zeros(bits.shape[0], np.int8)
    for i in range(bits.shape[0]):
        c, k, found = doubledigits._exact(np.int64(bits[i]) & 0x7FFFFFFFFFFFFFFF)
        cs[i], ks[i], st[i] = (c, k, 0) if found else (0, 0, 2)
    return cs, ks, st


def test_ryu_gives_the_exact_decimal_where_it_is_short():
    """Where a float64's exact decimal has at most 14 digits it is its shortest
    (`doubledigits._exact`, which `shortest_digits64` takes first): Ryu's steps give the
    same digits there, dyadic values of few bits, integers and their mixtures."""
    rng = np.random.default_rng(47)
    n = 30_000
    values = np.concatenate([rng.integers(-2**12, 2**12, n) / 2.0 ** rng.integers(0, 13, n),
                             rng.integers(-2**40, 2**40, n) / 2.0 ** rng.integers(0, 30, n),
                             rng.integers(-10**13, 10**13, n).astype(np.float64)])
    values = values[values != 0]
    bits = values.view(np.uint64)
    exact = exact_digits(bits)
    short = exact[2] == 0
    assert short.mean() > 0.5
    cs, ks = _ryu_digits(bits[short])
    assert np.array_equal(cs, exact[0][short]) and np.array_equal(ks, exact[1][short])
    found = shortest_digits64(bits)
    assert np.array_equal(found[0][short], exact[0][short]) and np.array_equal(found[1][short], exact[1][short])


def test_zero_infinities_and_nan_are_marked():
    values = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 1.0])
    _, _, status = shortest_digits64(values.view(np.uint64))
    assert status.tolist() == [1, 1, 2, 2, 2, 0]


@settings(max_examples=300, deadline=None)
@given(st.floats(allow_nan=False, allow_infinity=False).filter(lambda x: x != 0))
def test_any_float_gives_repr_s_digits(x):
    assert _mismatches(np.array([x])) == []


def test_double3_text_is_usd_s():
    """A response's CVs and offsets (``double3[]``) written from these digits are USD's text:
    values of every scale, signs, zeros, integers and the exponent layout's edges."""
    rng = np.random.default_rng(53)
    n = 30_000
    values = np.concatenate([rng.standard_normal(n) * 10.0 ** rng.integers(-30, 30, n),
                             rng.integers(1, 2**62, n, dtype=np.int64).astype(np.uint64).view(np.float64),
                             rng.integers(-10**6, 10**6, n) / 10.0 ** rng.integers(0, 12, n),
                             [0.0, -0.0, 1e-7, 1e-6, 9.999999999999999e-7, 1e14, 99999999999999.98, 1e15, 1e21, 5e-324, -1.7976931348623157e308]])
    values = np.ascontiguousarray(values[: values.size // 3 * 3].reshape(-1, 3))
    calls = []
    assert floattext.tuples_text(values, lambda v: calls.append(v) or _float_texts(v)).decode() == usd_array_text(values, "double3[]")
    assert calls == []


def test_every_layout_of_long_digits_is_usd_s():
    """`floattext._put_long` stores up to 18 digits in two stores of nine and ends the text where
    the value's does: values of 1 to 17 digits with the decimal point at every place (``0.00000d``
    to exponent form beyond 10^15), signed, beside each kind of neighbour; the text is USD's."""
    values = []
    for nd in range(1, 18):
        for point in range(-7, 18):
            c = int("12345678901234567"[:nd]) if nd % 2 else int("98765432109876543"[:nd])
            values += [float(f"{c}e{point - nd}"), -float(f"{c}e{point - nd}")]
    values = np.array(values + [1e15, 999999999999999.9, 1e-6, 9.999999999999999e-7, 0.5, 5.0])
    for shift in range(3):
        rows = np.ascontiguousarray(np.roll(values, shift)[: values.size // 3 * 3].reshape(-1, 3))
        assert floattext.tuples_text(rows, _float_texts).decode() == usd_array_text(rows, "double3[]")
        assert floattext.tuples_text(rows[::-1].copy(), _float_texts).decode() == usd_array_text(rows[::-1].copy(), "double3[]")
