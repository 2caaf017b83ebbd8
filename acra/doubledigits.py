"""Shortest round-trip digits of float64 values, compiled: the digits USD's ``.usda`` writer
prints for a ``double`` (``double3[]`` CVs and offsets of a response, ``double2[]`` surface
parameters).

USD's text writer prints a float64 as the shortest decimal that reads back as the same float64,
the closest to it where several are as short, the even one at a tie (double-conversion's
``ToShortest``). `shortest_digits64` finds those digits ``c 10^k``: a value's exact decimal
where it has at most 14 digits (`_exact`; then it is the shortest), else by Ryu's float64 algorithm
(Adams 2018, ``d2s``): a value ``m 2^e`` rounds back to itself from the interval between the
midpoints to its neighbours, ``[(4m - 2) 2^(e-2), (4m + 2) 2^(e-2)]`` (``4m - 1`` below a power
of two, ends included when ``m`` is even); the interval's ends and the value are scaled by
``10^-q`` (``q`` about log10 of the interval's width) through a 125-bit power of five, the
product kept to 64 bits, and decimal digits are dropped while the scaled ends still differ above
the last one. The last digit dropped decides the rounding, and where the product is exact
(a power of five or two divides the scaled end, tracked as "trailing zeros") a dropped ``5``
followed by zeros is a tie, which rounds to even. The 125-bit powers of five are held as pairs of
64-bit words (`_POW5_INV_SPLIT`, `_POW5_SPLIT`), their products with a 55-bit value formed from
32-bit halves (`_umul128`), since numba has no 128-bit integer. The text layout around the
digits is `acra.floattext`'s, the same as a float32's.

`tests/test_doubledigits.py` holds the digits to Python's ``repr`` (David Gay's shortest,
closest, ties to even) on seeded random bits of every exponent, subnormals and the powers of two
and ten, Ryu's digits to the exact decimals where those are short (`_exact`), and the text to USD's.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["shortest_digits64"]

_INV_BITS, _POW_BITS = 125, 125


def _pow5bits(e: int) -> int:
    """Bits of ``5^e`` (Ryu's ``pow5bits``, exact for ``0 <= e <= 3528``)."""
    return ((e * 1217359) >> 19) + 1


def _split(value: int) -> tuple[int, int]:
    """A 128-bit ``value`` as its (low, high) 64-bit words."""
    return value & (2**64 - 1), value >> 64


# 2^(pow5bits(q) - 1 + 125) / 5^q rounded up, for the values at or above 1 (q up to 290 over
# float64's exponents), and 5^i to its top 125 bits for those below (i up to 325): (k, 2) uint64,
# the low word first
_POW5_INV_SPLIT = np.array([_split(2 ** (_pow5bits(q) - 1 + _INV_BITS) // 5**q + 1) for q in range(342)], dtype=np.uint64)
_POW5_SPLIT = np.array([_split(5**i >> (_pow5bits(i) - _POW_BITS) if _pow5bits(i) >= _POW_BITS else 5**i << (_POW_BITS - _pow5bits(i)))
                        for i in range(326)], dtype=np.uint64)
_M32 = np.uint64(0xFFFFFFFF)
_POW5 = np.array([5**i for i in range(21)], dtype=np.int64)
_EXACT_MAX = 10**14  # a float64's exact decimal shorter than this is its shortest (see `_exact`)


@njit(cache=True, nogil=True, inline="always")
def _umul128(a, b):
    """``a b`` of two uint64 as its (high, low) 64-bit words, from the four products of their
    32-bit halves."""
    a_lo, a_hi = a & _M32, a >> np.uint64(32)
    b_lo, b_hi = b & _M32, b >> np.uint64(32)
    b00 = a_lo * b_lo
    b01 = a_lo * b_hi
    b10 = a_hi * b_lo
    b11 = a_hi * b_hi
    mid1 = b10 + (b00 >> np.uint64(32))  # below 2^64: (2^32 - 1)^2 + 2^32 - 1
    mid2 = b01 + (mid1 & _M32)
    hi = b11 + (mid1 >> np.uint64(32)) + (mid2 >> np.uint64(32))
    lo = (mid2 << np.uint64(32)) | (b00 & _M32)
    return hi, lo


@njit(cache=True, nogil=True, inline="always")
def _mul_shift64(m, lo, hi, j):
    """``(m (hi 2^64 + lo)) >> j`` for ``m < 2^55`` and ``64 <= j < 128`` (Ryu's ``mulShift64``;
    the result fits 64 bits)."""
    h0, _ = _umul128(m, lo)
    h1, l1 = _umul128(m, hi)
    s = l1 + h0
    if s < h0:  # the carry into the high word
        h1 += np.uint64(1)
    d = np.uint64(j - 64)
    if d == 0:
        return s
    return (h1 << (np.uint64(64) - d)) | (s >> d)


@njit(cache=True, nogil=True, inline="always")
def _pow5_factor(v):
    """How many times 5 divides ``v > 0`` (uint64)."""
    c = 0
    while v % np.uint64(5) == 0:
        v //= np.uint64(5)
        c += 1
    return c


@njit(cache=True, nogil=True)
def _d2s(bits):
    """Shortest digits ``(c, k)``, value ``c 10^k`` with ``c`` free of trailing zeros, of the
    float64 with ``bits`` (int64 pattern, sign cleared, finite, not zero; subnormals too), by
    Ryu's ``d2s`` (see the module's docstring)."""
    biased = bits >> 52
    frac = bits & 0xFFFFFFFFFFFFF
    # a subnormal is frac 2^-1074, a normal value (2^52 + frac) 2^(biased - 1075); both times 4
    e2 = biased - 1077 if biased > 0 else np.int64(-1076)
    m2 = np.uint64(frac | (np.int64(1) << 52) if biased > 0 else frac)
    even = (m2 & np.uint64(1)) == 0
    mv = np.uint64(4) * m2
    mm_shift = np.uint64(1 if (frac != 0 or biased <= 1) else 0)
    mp_ = mv + np.uint64(2)
    mm_ = mv - np.uint64(1) - mm_shift
    vm_tz = False
    vr_tz = False
    if e2 >= 0:
        q = ((e2 * 78913) >> 18) - (1 if e2 > 3 else 0)
        e10 = q
        k = _INV_BITS + ((q * 1217359) >> 19) + 1 - 1
        i = -e2 + q + k
        lo, hi = _POW5_INV_SPLIT[q, 0], _POW5_INV_SPLIT[q, 1]
        vr = _mul_shift64(mv, lo, hi, i)
        vp = _mul_shift64(mp_, lo, hi, i)
        vm = _mul_shift64(mm_, lo, hi, i)
        if q <= 21:
            # of mv, mp and mm at most one is a multiple of 5
            if mv % np.uint64(5) == 0:
                vr_tz = _pow5_factor(mv) >= q
            elif even:
                vm_tz = _pow5_factor(mm_) >= q
            elif _pow5_factor(mp_) >= q:
                vp -= np.uint64(1)
    else:
        q = ((-e2 * 732923) >> 20) - (1 if -e2 > 1 else 0)
        e10 = q + e2
        i = -e2 - q
        k = ((i * 1217359) >> 19) + 1 - _POW_BITS
        j = q - k
        lo, hi = _POW5_SPLIT[i, 0], _POW5_SPLIT[i, 1]
        vr = _mul_shift64(mv, lo, hi, j)
        vp = _mul_shift64(mp_, lo, hi, j)
        vm = _mul_shift64(mm_, lo, hi, j)
        if q <= 1:
            # mv = 4 m2 has two trailing zero bits; mm one exactly where mm_shift is 1
            vr_tz = True
            if even:
                vm_tz = mm_shift == 1
            else:
                vp -= np.uint64(1)
        elif q < 63:
            vr_tz = (mv & ((np.uint64(1) << np.uint64(q)) - np.uint64(1))) == 0
    removed = 0
    last = np.uint64(0)
    ten = np.uint64(10)
    if vm_tz or vr_tz:
        # the scaled values may be exact: a dropped 5 followed by zeros is a tie
        while vp // ten > vm // ten:
            vm_tz = vm_tz and vm % ten == 0
            vr_tz = vr_tz and last == 0
            last = vr % ten
            vr //= ten
            vp //= ten
            vm //= ten
            removed += 1
        if vm_tz:
            while vm % ten == 0:
                vr_tz = vr_tz and last == 0
                last = vr % ten
                vr //= ten
                vp //= ten
                vm //= ten
                removed += 1
        if vr_tz and last == 5 and vr % np.uint64(2) == 0:
            last = np.uint64(4)  # a tie: round to even
        up = (vr == vm and (not even or not vm_tz)) or last >= 5
    else:
        up = False
        hundred = np.uint64(100)
        if vp // hundred > vm // hundred:  # two digits at once, as most values drop at least two
            up = vr % hundred >= 50
            vr //= hundred
            vp //= hundred
            vm //= hundred
            removed += 2
        while vp // ten > vm // ten:
            up = vr % ten >= 5
            vr //= ten
            vp //= ten
            vm //= ten
            removed += 1
        up = up or vr == vm
    c = np.int64(vr) + (1 if up else 0)
    k10 = e10 + removed
    while c % 10 == 0:
        c //= 10
        k10 += 1
    return c, k10


@njit(cache=True, nogil=True, inline="always")
def _exact(b):
    """``(c, k, found)``: the exact decimal ``c 10^k`` (``c`` free of trailing zeros) of the
    finite nonzero float64 with ``b`` (int64 pattern, sign cleared) where ``c < 10^14``. Such a
    decimal is the shortest that reads back: any shorter one differs from it by at least 10^k,
    which is more than 10^-14 of the value, while a float64 reads back from within 2^-53 of it.
    A display's surface parameters (dyadic, few bits) are found here, where Ryu's steps would
    drop their many trailing digits one at a time."""
    biased = b >> 52
    if biased == 0:
        return np.int64(0), np.int64(0), False
    m = (b & 0xFFFFFFFFFFFFF) | (np.int64(1) << 52)
    e = biased - 1075  # value = m 2^e
    # drop trailing zero bits while the exponent is negative, by halving steps (a dyadic value
    # has up to 52)
    for step in (32, 16, 8, 4, 2, 1):
        if step <= -e and (m & ((np.int64(1) << step) - 1)) == 0:
            m >>= step
            e += step
    if e >= 0:
        if e > 47 or m > ((_EXACT_MAX - 1) >> e):
            return np.int64(0), np.int64(0), False
        c = m << e
        k = np.int64(0)
    else:
        if -e >= 21 or m > (_EXACT_MAX - 1) // _POW5[-e]:
            return np.int64(0), np.int64(0), False
        c = m * _POW5[-e]
        k = e
    while c % 10 == 0:
        c //= 10
        k += 1
    return c, k, True


@njit(cache=True, nogil=True)
def shortest_digits64(bits):
    """``(c, k, status)`` per float64 (``bits (n,)`` its uint64 pattern): ``|value| = c 10^k``,
    the shortest digits that read back, status 0 (the exact decimal where it has at most 14
    digits, `_exact`, else Ryu's, `_d2s`); 1 for zero; 2 for infinities and NaN, whose text the
    caller gives."""
    n = bits.shape[0]
    cs = np.zeros(n, np.int64)
    ks = np.zeros(n, np.int64)
    st = np.zeros(n, np.int8)
    for i in range(n):
        b = np.int64(bits[i]) & 0x7FFFFFFFFFFFFFFF
        if b == 0:
            st[i] = 1
        elif (b >> 52) == 0x7FF:
            st[i] = 2
        else:
            c, k, found = _exact(b)
            if not found:
                c, k = _d2s(b)
            cs[i], ks[i] = c, k
    return cs, ks, st
