"""Shortest round-trip digits of float32 values, compiled: the digits USD's ``.usda`` writer
prints for a ``float`` (``float3[]`` points and normals, and every float32 array it writes).

USD's text writer prints a float32 as the shortest decimal that reads back as the same float32,
the closest to it where several are as short, the even one at a tie. `shortest_digits` finds
those digits ``c 10^k`` for each value of an array, with exact integer arithmetic: a value
``M 2^E`` rounds back to itself from the interval ``[(4M - 2) 2^(E-2), (4M + 2) 2^(E-2)]``
(``4M - 1`` below a power of two, ends included when ``M`` is even); the multiples of ``10^k``
meet the interval for every ``k`` up to some largest ``K``, which gives the shortest digits. The
ends and the value are divided by ``10^k`` once, at ``k`` near log10 of the interval's width,
and then a digit at a time while the interval still holds a multiple; of the multiples of
``10^K`` within, the one closest to the value is taken, the even one where the value lies
midway between two (as double-conversion's exact fallback, which USD's writer uses, rounds).
That exact search (`_one`) fits 64 bits from about 1.5e-8 to 2^75 (`_RYU_BIASED`) and is the
reference the digits are held to; the digits are found by Ryu's float32 algorithm (`_ryu`,
64-bit tables, no loop over candidate exponents), which gives `_one`'s digits for every float32
there and USD's text for every float32 beyond, subnormals too. Infinities and NaN are marked
(status 2), and the caller formats them. The text layout around the digits is
`acra.floattext`'s, the same as a float64's (`acra.doubledigits`).

`tests/test_floatdigits.py` holds `_ryu`'s digits to `_one`'s over every exponent of
`_RYU_BIASED` and keeps samples of USD's text beyond it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from acra.doubledigits import _pow5_factor

__all__ = ["shortest_digits"]

_POW5 = np.array([5**i for i in range(28)], dtype=np.int64)


@njit(cache=True, nogil=True)
def _fits(a, shift):
    """Whether ``a << shift`` stays below 2^61 (``a`` positive)."""
    return shift < 61 and a < (np.int64(1) << (61 - shift))


@njit(cache=True, nogil=True)
def _floor_div(a, b, inv):
    """``a // b`` for positive ``a < 2^61`` and ``b`` (``inv`` about ``1 / b``), by a float
    quotient corrected exactly."""
    q = np.int64(np.float64(a) * inv)
    r = a - q * b
    while r < 0:
        q -= 1
        r += b
    while r >= b:
        q += 1
        r -= b
    return q


@njit(cache=True, nogil=True)
def _scaled(v, k, f, pow5):
    """``(A, B)`` with ``A / B = v 2^f / 10^k`` exactly, or ``(0, 0)`` where 64 bits cannot hold them."""
    if k >= 28 or -k >= 28:
        return np.int64(0), np.int64(0)
    five_a = pow5[-k] if k < 0 else np.int64(1)
    five_b = pow5[k] if k > 0 else np.int64(1)
    sh_a = f - k if f > k else 0
    sh_b = k - f if k > f else 0
    if five_a >= (np.int64(1) << 35) or not _fits(v * five_a, sh_a) or not _fits(five_b, sh_b):  # v < 2^26
        return np.int64(0), np.int64(0)
    return (v * five_a) << sh_a, five_b << sh_b


@njit(cache=True, nogil=True)
def _one(bits, pow5):
    """Shortest digits of the float32 with ``bits`` (sign cleared, finite): ``(c, k, status)``
    with value ``c 10^k``; status 0 found, 1 zero, 2 the caller formats it."""
    biased = (bits >> 23) & 0xFF
    frac = bits & 0x7FFFFF
    if biased == 0:
        return np.int64(0), np.int64(0), 1 if frac == 0 else 2
    m = frac | 0x800000
    f = biased - 152  # value = 4m 2^f; the interval's ends are integers times 2^f
    lo = 4 * m - 1 if (frac == 0 and biased > 1) else 4 * m - 2
    hi = 4 * m + 2
    inclusive = (m & 1) == 0
    # multiples of 10^k lie in the interval for every k up to the largest, K, and for every 10^k
    # at most its width (hi - lo) 2^f; start at the estimate of log10 of the width (lower by
    # one until the interval holds a multiple) and climb by dropping a digit at a time
    k = (f * 1262611 + 2516582) >> 22  # floor(0.6 + f log10 2); any start gives the same K
    while True:
        fa, b = _scaled(np.int64(1), k, f, pow5)
        if b == 0 or fa >= (np.int64(1) << 35):  # hi, the largest of the three, is below 2^26
            return np.int64(0), np.int64(0), 2
        a_hi = hi * fa
        a_lo = lo * fa
        a_x = 4 * m * fa
        inv = 1.0 / np.float64(b)
        qh = _floor_div(a_hi, b, inv)
        ql = _floor_div(a_lo, b, inv)
        qx = _floor_div(a_x, b, inv)
        hz = qh * b == a_hi  # the end is a multiple of 10^k
        lz = ql * b == a_lo
        rx2 = 2 * (a_x - qx * b)
        xcmp = 1 if rx2 > b else (0 if rx2 == b else -1)  # the value's fraction against one half
        xz = rx2 == 0
        top = qh - 1 if (hz and not inclusive) else qh
        if top > ql or (top == ql and lz and inclusive):
            break
        k -= 1
    while True:
        nh = qh // 10
        nl = ql // 10
        nhz = hz and qh == nh * 10
        nlz = lz and ql == nl * 10
        ntop = nh - 1 if (nhz and not inclusive) else nh
        if not (ntop > nl or (ntop == nl and nlz and inclusive)):
            break
        qh, hz, ql, lz, top = nh, nhz, nl, nlz, ntop
        nx = qx // 10
        d = qx - nx * 10
        qx = nx
        xcmp = 1 if d > 5 else (-1 if d < 5 else (1 if not xz else 0))
        xz = xz and d == 0
        k += 1
    # of the multiples within, the one nearest the value, the even one at a tie
    c = qx + 1 if xcmp > 0 else (qx + (qx & 1) if xcmp == 0 else qx)
    bottom = ql if (lz and inclusive) else ql + 1
    if c > top:
        c = top
    if c < bottom:
        c = bottom
    while c % 10 == 0:
        c //= 10
        k += 1
    return c, k, 0


def _pow5bits(e):
    """Bits of ``5^e`` (Ryu's ``pow5bits``)."""
    return ((e * 1217359) >> 19) + 1


_INV_BITS, _POW_BITS = 59, 61
# biased float32 exponents where `_one`'s exact search fits 64 bits at every value (1.5e-8 up to
# 2^75): the range `tests/test_floatdigits.py` holds `_ryu`'s digits to `_one`'s over
_RYU_BIASED = (101, 201)
_POW5_INV_SPLIT = np.array([(2 ** (_pow5bits(q) - 1 + _INV_BITS)) // (5 ** q) + 1 for q in range(31)], dtype=np.uint64)
_POW5_SPLIT = np.array([(5 ** i) >> (_pow5bits(i) - _POW_BITS) if _pow5bits(i) >= _POW_BITS else (5 ** i) << (_POW_BITS - _pow5bits(i)) for i in range(48)], dtype=np.uint64)


@njit(cache=True, nogil=True, inline="always")
def _mul_shift(m, factor, shift):
    """``(m factor) >> shift`` of ``m < 2^32`` and a 64-bit ``factor``, in 64-bit halves."""
    lo = factor & np.uint64(0xFFFFFFFF)
    hi = factor >> np.uint64(32)
    b0 = m * lo
    b1 = m * hi
    return ((b0 >> np.uint64(32)) + b1) >> np.uint64(shift - 32)


@njit(cache=True, nogil=True, inline="always")
def _pow5bits_n(e):
    """`_pow5bits`, compiled."""
    return ((e * 1217359) >> 19) + 1


@njit(cache=True, nogil=True)
def _ryu(bits):
    """Shortest digits ``(c, k)``, value ``c 10^k``, of the float32 with ``bits`` (sign cleared,
    finite, not zero; subnormals too), by Ryu (Adams 2018, ``f2s``): the interval's ends and the
    value are scaled by ``10^-q`` with 64-bit tables of powers of 5 (`_POW5_INV_SPLIT`,
    `_POW5_SPLIT`), digits are dropped while the ends differ above the last, and the value rounds
    to the nearest, the even one at a tie. Its answers are `_one`'s, every float32 of
    `_RYU_BIASED`'s exponents compared, and USD's text elsewhere (`tests/test_floatdigits.py`
    keeps samples of both)."""
    biased = np.int64(bits >> 23)
    frac = np.int64(bits & 0x7FFFFF)
    # a subnormal is frac 2^-149, a normal value (2^23 + frac) 2^(biased - 150); both times 4 here
    e2 = biased - 152 if biased > 0 else np.int64(-151)
    m2 = frac | 0x800000 if biased > 0 else frac
    even = (m2 & 1) == 0
    mv = np.uint64(4 * m2)
    mp = np.uint64(4 * m2 + 2)
    mm_shift = 1 if (frac != 0 or biased <= 1) else 0
    mm = np.uint64(4 * m2 - 1 - mm_shift)
    vm_tz = False
    vr_tz = False
    last = np.uint64(0)
    if e2 >= 0:
        q = (e2 * 78913) >> 18
        e10 = q
        k = _INV_BITS + _pow5bits_n(q) - 1
        i = -e2 + q + k
        f = _POW5_INV_SPLIT[q]
        vr = _mul_shift(mv, f, i)
        vp = _mul_shift(mp, f, i)
        vm = _mul_shift(mm, f, i)
        if q != 0 and (vp - np.uint64(1)) // np.uint64(10) <= vm // np.uint64(10):
            l = _INV_BITS + _pow5bits_n(q - 1) - 1
            last = _mul_shift(mv, _POW5_INV_SPLIT[q - 1], -e2 + q - 1 + l) % np.uint64(10)
        if q <= 9:
            if mv % np.uint64(5) == 0:
                vr_tz = _pow5_factor(mv) >= q
            elif even:
                vm_tz = _pow5_factor(mm) >= q
            else:
                vp -= np.uint64(1 if _pow5_factor(mp) >= q else 0)
    else:
        q = (-e2 * 732923) >> 20
        e10 = q + e2
        i = -e2 - q
        k = _pow5bits_n(i) - _POW_BITS
        j = q - k
        f = _POW5_SPLIT[i]
        vr = _mul_shift(mv, f, j)
        vp = _mul_shift(mp, f, j)
        vm = _mul_shift(mm, f, j)
        if q != 0 and (vp - np.uint64(1)) // np.uint64(10) <= vm // np.uint64(10):
            j = q - 1 - (_pow5bits_n(i + 1) - _POW_BITS)
            last = _mul_shift(mv, _POW5_SPLIT[i + 1], j) % np.uint64(10)
        if q <= 1:
            vr_tz = True
            if even:
                vm_tz = mm_shift == 1
            else:
                vp -= np.uint64(1)
        elif q < 31:
            vr_tz = (mv & ((np.uint64(1) << np.uint64(q - 1)) - np.uint64(1))) == 0
    removed = 0
    if vm_tz or vr_tz:
        while vp // np.uint64(10) > vm // np.uint64(10):
            vm_tz = vm_tz and vm % np.uint64(10) == 0
            vr_tz = vr_tz and last == 0
            last = vr % np.uint64(10)
            vr //= np.uint64(10)
            vp //= np.uint64(10)
            vm //= np.uint64(10)
            removed += 1
        if vm_tz:
            while vm % np.uint64(10) == 0:
                vr_tz = vr_tz and last == 0
                last = vr % np.uint64(10)
                vr //= np.uint64(10)
                vp //= np.uint64(10)
                vm //= np.uint64(10)
                removed += 1
        if vr_tz and last == 5 and vr % np.uint64(2) == 0:
            last = np.uint64(4)
        up = (vr == vm and (not even or not vm_tz)) or last >= 5
    else:
        while vp // np.uint64(10) > vm // np.uint64(10):
            last = vr % np.uint64(10)
            vr //= np.uint64(10)
            vp //= np.uint64(10)
            vm //= np.uint64(10)
            removed += 1
        up = vr == vm or last >= 5
    c = np.int64(vr) + (1 if up else 0)
    k10 = e10 + removed
    while c % 10 == 0:
        c //= 10
        k10 += 1
    return c, k10


@njit(cache=True, nogil=True)
def shortest_digits(bits, ref=None, same=None):
    """``(c, k, status)`` per float32 (``bits`` its uint32 pattern): ``|value| = c 10^k`` with
    status 0, 1 for zero, 2 where the caller formats the value. With ``ref`` (the bits of an
    array of the same size) and ``same`` (one flag per tuple of ``bits.shape[0] // same.shape[0]``
    values; empty: every value's digits), ``same[t]`` is set where tuple ``t``'s bits are
    ``ref``'s, whose digits are left zero (their text is the reference's)."""
    n = bits.shape[0]
    cs = np.zeros(n, np.int64)
    ks = np.zeros(n, np.int64)
    st = np.zeros(n, np.int8)
    m = 1
    check = ref is not None and same is not None and same.shape[0] > 0
    if check:
        m = n // same.shape[0]
        for t in range(same.shape[0]):
            same[t] = True
            for j in range(t * m, t * m + m):
                if bits[j] != ref[j]:
                    same[t] = False
                    break
    for i in range(n):
        if check and same[i // m]:
            continue
        b = np.int64(bits[i]) & 0x7FFFFFFF
        if (b >> 23) == 0xFF:
            st[i] = 2
            continue
        if b == 0:
            st[i] = 1
            continue
        cs[i], ks[i] = _ryu(b)
    return cs, ks, st
