"""`acra.floatdigits` finds each float32's shortest round-trip digits as USD's ``.usda`` writer
prints them: Ryu's steps (`_ryu`) held to the exact integer search (`_one`) over its range and,
through `acra.floattext`, to USD's text beyond it."""

from __future__ import annotations

import numpy as np

from acra import floatdigits, floattext
from pipeline.output_layer import _float_texts

from conftest import usd_array_text


def test_digits_are_found_for_the_usual_range():
    """Values from 1.03e-7 to 2^40 are formatted by the kernel, not handed back."""
    rng = np.random.default_rng(3)
    values = (rng.choice([-1.0, 1.0], 30000) * 10.0 ** rng.uniform(-6.99, 11.9, 30000)).astype(np.float32)
    _, _, status = floatdigits.shortest_digits(values.view(np.uint32))
    assert not np.any(status == 2)


def test_ryu_gives_the_exact_digits_across_its_range():
    """`floatdigits._ryu` (the fast path of `shortest_digits`) gives the digits of the exact
    search `_one` at random float32s of every exponent it formats, at its range's ends and at
    the powers of two (every float32 of the range was compared once, 101 x 2^23 values)."""
    from numba import njit

    @njit
    def mismatches(bits):
        bad = 0
        for b in bits:
            c, k, s = floatdigits._one(np.int64(b), floatdigits._POW5)
            c2, k2 = floatdigits._ryu(np.int64(b))
            bad += s != 0 or c != c2 or k != k2
        return bad

    lo, hi = floatdigits._RYU_BIASED
    rng = np.random.default_rng(7)
    exps = np.arange(lo, hi + 1, dtype=np.int64)
    bits = (rng.integers(lo, hi + 1, 2_000_000) << 23) | rng.integers(0, 2**23, 2_000_000)
    edges = np.concatenate([exps << 23, (exps << 23) | 1, (exps << 23) | (2**23 - 1), (exps << 23) | 2**22])
    assert mismatches(np.concatenate([bits, edges])) == 0


def test_ryu_gives_usd_s_text_beyond_the_exact_search_s_range():
    """Below 1.5e-8 (subnormals too) and at or above 2^75, where `_one`'s exact search would
    overflow 64 bits, `_ryu`'s digits give USD's text, none left to USD's writer (every float32
    of those exponents was compared once, 154 x 2^23 values); random values of every such
    exponent, both signs, and each exponent's ends and middle."""
    lo, hi = floatdigits._RYU_BIASED
    exps = np.concatenate([np.arange(0, lo), np.arange(hi + 1, 255)]).astype(np.uint64)
    rng = np.random.default_rng(29)
    n = 150_000
    bits = (rng.choice(exps, n) << np.uint64(23)) | rng.integers(0, 2**23, n).astype(np.uint64)
    bits |= rng.integers(0, 2, n).astype(np.uint64) << np.uint64(31)
    edges = np.concatenate([exps << np.uint64(23), (exps << np.uint64(23)) | np.uint64(1), (exps << np.uint64(23)) | np.uint64(2**23 - 1),
                            (exps << np.uint64(23)) | np.uint64(2**22)])
    values = np.concatenate([bits, edges]).astype(np.uint32).view(np.float32)
    values = np.ascontiguousarray(values[: values.size // 3 * 3].reshape(-1, 3))
    calls = []
    assert floattext.tuples_text(values, lambda v: calls.append(v) or _float_texts(v)).decode() == usd_array_text(values, "float3[]")
    assert calls == []
    _, _, status = floatdigits.shortest_digits(values.reshape(-1).view(np.uint32))
    assert not np.any(status == 2)
