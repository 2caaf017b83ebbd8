"""Arrays as ``.usda`` text, compiled: the bytes USD's text writer gives, faster.

A ``.usda`` layer writes each float of a ``float3[]`` value as the shortest decimal that reads
back as the same float32, the closest to it where several are as short, in ECMAScript's layout
(decimal point notation for decimal exponents -6 to 14, ``1.5e-7`` / ``1e15`` beyond; ``-0`` for
negative zero) and ``[(x, y, z), ...]`` around them. `tuples_text` writes that text for a
``(n, m)`` float32 array from each value's shortest digits (`acra.floatdigits`: Ryu's float32
algorithm, held to an exact integer search). Infinities and NaN are marked, and the caller
supplies their text (``hard``). A float32
array's text is written in one pass (`_float32_text`), each value's digits as they are found,
after `_marks` has found the values handed to the caller; a value of at most nine digits with
its decimal point among them is stored as nine digits at once (`_put_short`), the rare others
out of the loop's way. Each text is written into a buffer of its bound and the buffer cut to it. A float64
array's values are written from their shortest digits (`acra.doubledigits.shortest_digits64`:
a float64's exact decimal where it has at most 14 digits, Ryu's float64 algorithm otherwise) in
the same layout. An int array's values are written as their digits (`ints_text`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from acra.doubledigits import shortest_digits64
from acra.floatdigits import _ryu, shortest_digits

__all__ = ["ints_text", "tuples_text", "tuples_texts"]

# decimal exponents printed in decimal point notation: LOW <= exponent < HIGH
_LOW, _HIGH = -6, 15
_POW10 = np.array([10**i for i in range(19)], dtype=np.int64)
# no values left to the caller; bytes arrays read-only, as `np.frombuffer` makes them (one
# specialisation of the kernels that take them)
_NO_BYTES, _ONE_START = np.frombuffer(b"", np.uint8), np.zeros(1, np.int64)
_PAIRS = np.frombuffer("".join(f"{i:02d}" for i in range(100)).encode(), np.uint8).copy()  # "00" .. "99"


@njit(cache=True, nogil=True, inline="always")
def _copy_shared(buf, at, starts, ref_at, ref_text, t, n, same):
    """Copy the run of tuples ``t`` up to the first one ``same (n,) bool`` does not mark from the
    reference's text ``ref_text (b,) uint8`` (tuple ``q``'s text at ``ref_at[q]``) into ``buf``
    at ``at``, with their separators, setting their ``starts``; returns the new ``at`` and the
    run's end. A shared tuple's text is its reference's bytes, so the run is one block copy."""
    e = t + 1
    while e < n and same[e]:
        e += 1
    shift = at - ref_at[t]
    for q in range(t, e):
        starts[q] = ref_at[q] + shift
    size = ref_at[e] - 2 - ref_at[t]
    into, part = buf[at:], ref_text[ref_at[t]:]  # indices from 0 up: the copy compiles to a block copy
    for q in range(size):
        into[q] = part[q]
    return at + size, e


@njit(cache=True, nogil=True)
def _ndigits(c):
    """Decimal digits of ``0 <= c < 10^18``."""
    if c < 10**9:
        return (1 + (c >= 10) + (c >= 100) + (c >= 1000) + (c >= 10**4) + (c >= 10**5) + (c >= 10**6)
                + (c >= 10**7) + (c >= 10**8))
    n = 10
    while c >= _POW10[n]:
        n += 1
    return n


@njit(cache=True, nogil=True, inline="always")
def _put_tail(buf, j, c):
    """The decimal digits of ``c >= 0`` written right to left so that the last is ``buf[j - 1]``,
    two at a time from `_PAIRS`."""
    while c >= 100:
        r = c % 100
        c //= 100
        buf[j - 1] = _PAIRS[2 * r + 1]
        buf[j - 2] = _PAIRS[2 * r]
        j -= 2
    if c >= 10:
        buf[j - 1] = _PAIRS[2 * c + 1]
        buf[j - 2] = _PAIRS[2 * c]
    else:
        buf[j - 1] = 48 + c


@njit(cache=True, nogil=True)
def _put_digits(buf, at, c, nd, point):
    """The ``nd`` digits of ``c`` from ``buf[at]``, a ``.`` after the first ``point`` of them
    (none if ``point`` is not within them); the index after them."""
    inside = 0 < point < nd
    first = at + 1 if inside else at  # the digits, then the first ``point`` moved left by one
    j = first + nd
    _put_tail(buf, j, c)
    if inside:
        for q in range(point):
            buf[at + q] = buf[at + 1 + q]
        buf[at + point] = 46
    return first + nd


@njit(cache=True, nogil=True)
def _put_value(buf, at, c, k, s, neg):
    """One value's text from ``buf[at]`` (status 0 or 1); the index after it."""
    if neg:
        buf[at] = 45  # '-'
        at += 1
    if s == 1:
        buf[at] = 48
        return at + 1
    nd = _ndigits(c)
    point = nd + k  # the decimal point's place after the first digit
    exp = point - 1
    if _LOW <= exp < _HIGH:
        if point <= 0:
            buf[at] = 48
            buf[at + 1] = 46
            at += 2
            for _ in range(-point):
                buf[at] = 48
                at += 1
            return _put_digits(buf, at, c, nd, 0)
        at = _put_digits(buf, at, c, nd, point)
        for _ in range(point - nd):
            buf[at] = 48
            at += 1
        return at
    at = _put_digits(buf, at, c, nd, 1)
    buf[at] = 101  # 'e'
    at += 1
    if exp < 0:
        buf[at] = 45
        at += 1
        exp = -exp
    return _put_digits(buf, at, exp, _ndigits(exp), 0)


@njit(cache=True, nogil=True)
def _tuples_text(n, m, neg, cs, ks, st, hard_bytes, hard_at, same, ref_text, ref_at, buf):
    """``[(a, b, c), ...]`` of ``n`` tuples of ``m`` values (``neg`` their signs, flattened)
    from each value's digits (`shortest_digits`, `shortest_digits64`) or, at status 2, the bytes
    ``hard_bytes[hard_at[i]:hard_at[i + 1]]`` of its rank ``i`` among the status-2 values; a
    tuple with ``same[t]`` set is the same values as tuple ``t`` of a reference array, whose text
    ``ref_text`` holds it from ``ref_at[t]`` up to ``ref_at[t + 1] - 2`` and is copied from there
    (``same`` empty: none). The text is written from ``buf[0]`` (``buf`` of `_tuples_bound`
    bytes at least); returns its length and where each tuple's text starts in it, in the
    layout of ``ref_at`` (``n + 1`` entries, the last two past the closing ``)``)."""
    starts = np.empty(n + 1, np.int64)
    buf[0] = 91  # '['
    at = 1
    h = np.int64(0)  # not a literal: the calls taking it compile once
    t = 0
    while t < n:
        if t > 0:
            buf[at] = 44
            buf[at + 1] = 32
            at += 2
        if same.shape[0] > 0 and same[t]:
            # a run of tuples the reference shares: its text and separators are copied at once
            at, t = _copy_shared(buf, at, starts, ref_at, ref_text, t, n, same)
            continue
        starts[t] = at
        buf[at] = 40  # '('
        at += 1
        for j in range(m):
            if j > 0:
                buf[at] = 44
                buf[at + 1] = 32
                at += 2
            i = t * m + j
            if st[i] == 0:
                end = _put_short(buf, at, cs[i], ks[i], neg[i])
                if end < 0:
                    end = _put_long(buf, -1 - end, cs[i], ks[i])
                if end >= 0:
                    at = end
                    continue
            at, h = _put_found(buf, at, cs[i], ks[i], np.int64(st[i]), neg[i], hard_bytes, hard_at, h)
        buf[at] = 41  # ')'
        at += 1
        t += 1
    buf[at] = 93  # ']'
    starts[n] = at + 2
    return at + 1, starts


@njit(cache=True, nogil=True, inline="always")
def _put_nine(buf, at, d):
    """The nine decimal digits of ``0 <= d < 10^9``, leading zeros too, at ``buf[at:at + 9]``:
    a fixed number of stores whatever the value, in unsigned arithmetic (no floor correction of
    a quotient, no wraparound test of an index)."""
    u = np.uint64(at)
    d = np.uint64(d)
    top = d // np.uint64(100000000)
    d -= top * np.uint64(100000000)
    a = d // np.uint64(1000000)
    d -= a * np.uint64(1000000)
    b = d // np.uint64(10000)
    d -= b * np.uint64(10000)
    c = d // np.uint64(100)
    d -= c * np.uint64(100)
    one = np.uint64(1)
    buf[u] = np.uint8(48) + np.uint8(top)
    buf[u + one] = _PAIRS[a + a]
    buf[u + np.uint64(2)] = _PAIRS[a + a + one]
    buf[u + np.uint64(3)] = _PAIRS[b + b]
    buf[u + np.uint64(4)] = _PAIRS[b + b + one]
    buf[u + np.uint64(5)] = _PAIRS[c + c]
    buf[u + np.uint64(6)] = _PAIRS[c + c + one]
    buf[u + np.uint64(7)] = _PAIRS[d + d]
    buf[u + np.uint64(8)] = _PAIRS[d + d + one]


@njit(cache=True, nogil=True, inline="always")
def _put_fraction_start(buf, u):
    """``0.`` and five zeros at ``u``: the start of a value below 1 in decimal point notation
    (`_put_short`, `_put_long`), whose digits are then stored from the first place they need."""
    buf[u] = 48
    buf[u + np.uint64(1)] = 46
    for q in range(np.uint64(2), np.uint64(7)):
        buf[u + q] = 48


@njit(cache=True, nogil=True, inline="always")
def _put_short(buf, at, c, k, neg):
    """A nonzero value's text from its digits ``c 10^k`` (``0 < c < 10^18``) where they are at
    most nine and the decimal point falls within the first nine places (every float32 from 1e-6
    to 1e9); the index after it, or ``-1 - at`` (``at`` after the sign) for `_put_text`.

    The digits are written as nine, left-justified (``c 10^(9 - nd)``: the value's digits, then
    zeros), in a fixed number of stores, and the text ends where the value's does: the stores
    past its end (within 17 bytes of the value's start, the buffer's bound a value) are written
    over by what follows. The layouts differ in where the nine go and the point: ``0.00ddd``
    (the nine after the zeros), ``dd.ddd`` (the nine one place right, the integer's digits moved
    back over the gap by a fixed nine selects) and ``ddd00`` (the same, the point past the end).
    Nothing here branches on a count of digits: a loop of data-dependent length mispredicts."""
    buf[at] = 45  # '-', kept by a negative value only
    at += 1 if neg else 0
    nd = _ndigits(c)
    point = nd + k  # the decimal point's place after the first digit
    if nd > 9 or point <= _LOW or point > 9:
        return -1 - at
    d = c * _POW10[9 - nd]
    u = np.uint64(at)
    if point <= 0:  # "0.", up to five zeros, then the digits
        _put_fraction_start(buf, u)
        at += 2 - point
        _put_nine(buf, at, d)
        return at + nd
    _put_nine(buf, at + 1, d)
    p = np.uint64(point)
    for q in range(np.uint64(9)):
        buf[u + q] = buf[u + q + np.uint64(1)] if q < p else buf[u + q]
    buf[u + p] = 46
    return at + nd + 1 if point < nd else at + point


@njit(cache=True, nogil=True, inline="always")
def _put_long(buf, at, c, k):
    """`_put_short` of a value of up to 18 digits ``c 10^k`` (a float64's 17) whose decimal
    point falls within its digits or before them (``0.00ddd`` to ``d.ddd``, decimal exponents -6
    to 14), its sign written:
    the digits as eighteen, left-justified, in two stores of nine (`_put_nine`), the integer's
    digits moved back over the gap by a fixed eighteen selects and the text ended where the
    value's does (the stores past it, within 26 bytes of the value's start, are written over by
    what follows); the index after it, or -1 for `_put_text`'s layouts."""
    nd = _ndigits(c)
    point = nd + k
    if point <= _LOW or point >= nd or point > _HIGH:
        return np.int64(-1)
    d = c * _POW10[18 - nd]
    hi = d // 1000000000
    lo = d - hi * 1000000000
    u = np.uint64(at)
    if point <= 0:  # "0.", up to five zeros, then the digits
        _put_fraction_start(buf, u)
        at += 2 - point
        _put_nine(buf, at, hi)
        _put_nine(buf, at + 9, lo)
        return at + nd
    _put_nine(buf, at + 1, hi)
    _put_nine(buf, at + 10, lo)
    p = np.uint64(point)
    for q in range(np.uint64(18)):
        buf[u + q] = buf[u + q + np.uint64(1)] if q < p else buf[u + q]
    buf[u + p] = 46
    return at + nd + 1


@njit(cache=True, nogil=True, inline="always")
def _put_nonzero(buf, at, c, k, neg):
    """`_put_value` of a nonzero value's digits ``c 10^k`` (``0 < c < 10^18``): `_put_short`,
    else `_put_text`."""
    end = _put_short(buf, at, c, k, neg)
    if end < 0:
        nd = _ndigits(c)
        end = _put_text(buf, -1 - end, c, k, nd, nd + k)
    return end


@njit(cache=True, nogil=True)
def _put_text(buf, at, c, k, nd, point):
    """`_put_nonzero`'s text of the unsigned value ``c 10^k`` of ``nd`` digits, its decimal point
    after the first ``point``, the digits written from the last, the point in its place as they
    go (no shift)."""
    if point <= _LOW or point > _HIGH:
        return _put_value(buf, at, c, k, 0, False)
    if point <= 0:  # "0.", zeros, then every digit
        buf[at] = 48
        buf[at + 1] = 46
        at += 2
        for _ in range(-point):
            buf[at] = 48
            at += 1
        end = at + nd
        j = end
    elif point >= nd:  # the digits, then zeros
        end = at + point
        for q in range(at + nd, end):
            buf[q] = 48
        j = at + nd
    else:  # the fraction's digits, the point, then the integer's
        end = at + nd + 1
        j = end
        frac = nd - point
        while frac >= 2:
            r = c % 100
            c //= 100
            buf[j - 1] = _PAIRS[2 * r + 1]
            buf[j - 2] = _PAIRS[2 * r]
            j -= 2
            frac -= 2
        if frac == 1:
            buf[j - 1] = 48 + c % 10
            c //= 10
            j -= 1
        j -= 1
        buf[j] = 46
    _put_tail(buf, j, c)
    return end


@njit(cache=True, nogil=True)
def _marks(bits, m, ref, same):
    """Which values of the float32 ``bits`` (tuples of ``m``) the caller formats: the indices
    of those `acra.floatdigits._one` hands back (status 2), in order, in tuples whose bits differ from ``ref``'s
    (``ref`` empty: every tuple). ``same[t]`` is set where tuple ``t``'s bits are ``ref``'s
    (``same`` empty: none is compared)."""
    n = bits.shape[0] // m
    check = same.shape[0] > 0
    hard = np.empty(bits.shape[0], np.int64)
    h = 0
    for t in range(n):
        if check:
            eq = True
            for j in range(t * m, t * m + m):
                if bits[j] != ref[j]:
                    eq = False
                    break
            same[t] = eq
            if eq:
                continue
        for i in range(t * m, t * m + m):
            if (bits[i] >> 23) & 0xFF == 0xFF:  # inf and NaN
                hard[h] = i
                h += 1
    return hard[:h].copy()


@njit(cache=True, nogil=True)
def _float32_text(bits, m, same, hard_bytes, hard_at, ref_text, ref_at, buf):
    """``[(a, b, c), ...]`` of the float32 ``bits`` in tuples of ``m``, each value its shortest
    digits (`_ryu`) in USD's layout, or the bytes ``hard_bytes[hard_at[i]:hard_at[i
    + 1]]`` for the ``i``-th value `_marks` handed to the caller; a run of tuples with ``same``
    set is copied at once from the reference's text ``ref_text`` (its tuple ``t`` from
    ``ref_at[t]`` up to ``ref_at[t + 1] - 2``). One pass, digits written as they are found.
    The text is written from ``buf[0]`` (``buf`` of `_tuples_bound` bytes at least); returns
    its length and where each tuple's text starts in it (``n + 1`` entries, the last past the
    closing ``]``), the layout of ``ref_at``."""
    n = bits.shape[0] // m
    check = same.shape[0] > 0
    starts = np.empty(n + 1, np.int64)
    buf[0] = 91  # '['
    at = 1
    h = np.int64(0)  # not a literal: the calls taking it compile once
    t = 0
    while t < n:
        if t > 0:
            buf[at] = 44
            buf[at + 1] = 32
            at += 2
        if check and same[t]:
            at, t = _copy_shared(buf, at, starts, ref_at, ref_text, t, n, same)
            continue
        starts[t] = at
        buf[at] = 40  # '('
        at += 1
        for i in range(t * m, t * m + m):
            if i > t * m:
                buf[at] = 44
                buf[at + 1] = 32
                at += 2
            b = np.int64(bits[i])
            neg = (b >> 31) & 1 == 1
            b &= 0x7FFFFFFF
            if b != 0 and (b >> 23) != 0xFF:
                c, k = _ryu(b)
                end = _put_short(buf, at, c, k, neg)
                if end >= 0:
                    at = end
                    continue
            at, h = _put_rare(buf, at, b, neg, hard_bytes, hard_at, h)
        buf[at] = 41  # ')'
        at += 1
        t += 1
    buf[at] = 93  # ']'
    starts[n] = at + 2
    return at + 1, starts


@njit(cache=True, nogil=True)
def _put_rare(buf, at, b, neg, hard_bytes, hard_at, h):
    """`_float32_text`'s value of ``bits`` ``b`` (sign cleared, ``neg`` its sign) that
    `_put_short` leaves: zero, digits `acra.floatdigits._one` finds, or the ``h``-th of the texts left to the
    caller; the index after it and the next ``h``. Out of the loop's way: a call inlined there
    slows every value's path."""
    if b == 0:
        return _put_value(buf, at, 0, 0, 1, neg), h
    if (b >> 23) != 0xFF:
        c, k = _ryu(b)
        return _put_nonzero(buf, at, c, k, neg), h
    return _put_found(buf, at, np.int64(0), np.int64(0), np.int64(2), neg, hard_bytes, hard_at, h)


@njit(cache=True, nogil=True)
def _put_found(buf, at, c, k, s, neg, hard_bytes, hard_at, h):
    """A value's text from its digits ``c 10^k`` and status ``s`` (0 found, 1 zero, 2 the
    ``h``-th of the texts left to the caller, ``hard_bytes[hard_at[h]:hard_at[h + 1]]``); the
    index after it and the next ``h``."""
    if s == 2:
        for q in range(hard_at[h], hard_at[h + 1]):
            buf[at] = hard_bytes[q]
            at += 1
        return at, h + 1
    return (_put_nonzero(buf, at, c, k, neg) if s == 0 else _put_value(buf, at, c, k, s, neg)), h


def _tuples_bound(values: np.ndarray, hard_bytes: np.ndarray, ref_text: np.ndarray) -> int:
    """Bytes enough for the text of ``values (n, m)``: a float32 takes at most 17 characters
    (sign, "0.", 5 zeros, 9 digits), a float64 25 (17 digits), each 2 of
    separator and a tuple 4 more, the texts left to the caller theirs; a copied run is at most
    its reference's text."""
    n, m = values.shape
    return 2 + n * (m * (27 if values.dtype == np.float64 else 19) + 4) + hard_bytes.shape[0] + ref_text.shape[0]


def _trimmed(buf: np.ndarray, size: int) -> np.ndarray:
    """``buf``'s first ``size`` bytes as ``buf`` itself, its memory shrunk to them in place
    (``realloc``: no copy of the text, and no more memory held than the text's)."""
    buf.resize(size, refcheck=False)  # buf: made here, no view of it anywhere
    return buf


def tuples_text(values: np.ndarray, hard) -> bytes:
    """The text of ``values (n, m)`` (float32 or float64, finite) as ``[(a, b, c), ...]``;
    ``hard(v)`` gives the texts (a list of str) of the values ``v`` (of the same type) this
    does not format (infinities and NaN: `shortest_digits`, `shortest_digits64` status 2)."""
    return tuples_texts([values], hard)[0].tobytes()


# the values (of tuples changed from the reference, or of every tuple) a side of `tuples_texts`
# must hold before a second thread formats it: below this, the thread's start and the GIL handed
# over at each kernel cost more than the values' text
SIDE_MIN = 20000


def tuples_texts(arrays: list, hard, refs: list | None = None, both=None) -> list[np.ndarray]:
    """`tuples_text` of each of ``arrays`` as a read-only ``(bytes,) uint8`` array, with one
    call of ``hard`` for each type's values left to it (USD's writer has a fixed cost a call).
    ``refs[i]``, where given, is the index ``j < i`` of an array whose text serves
    ``arrays[i]``: the tuples of ``arrays[i]`` whose bits equal the same tuple's of
    ``arrays[j]`` (same shape and type) are copied from ``j``'s text, not formatted again (a
    response moves a display's points near the contact alone). Each text is written into its
    own buffer and the buffer cut to it, not copied out.

    ``both(first, second)``, where given, runs two calls and returns their answers (e.g.
    `pipeline.workers.both`, side by side): the arrays' chains of references (an attribute's
    samples) are dealt to two sides of about equal work (`_sides`), each side's values found and
    then formatted by one call of each side. A chain is one side's alone, every text is made from
    its own array and reference's text alone, and ``hard`` is called once a type in the caller,
    so the texts are the bytes one call gives."""
    refs = list(refs) if refs is not None else [None] * len(arrays)
    done: list = [None] * len(arrays)
    chains = _chains(refs)
    sides = _sides(chains, [np.size(a) for a in arrays], both)
    _run_sides(both, [lambda side=side: _found(arrays, refs, done, side) for side in sides])
    # each array's values left to ``hard``: their texts' bytes end to end and where each starts
    texts: list = [(_NO_BYTES, _ONE_START)] * len(done)
    for dtype in (np.float32, np.float64):
        which = [i for i, d in enumerate(done) if d[0].dtype == dtype and d[2].size]
        if which:
            got = hard(np.concatenate([done[i][0].reshape(-1)[done[i][2]] for i in which]))
            at = np.zeros(len(got) + 1, np.int64)
            np.cumsum(np.fromiter(map(len, got), np.int64, len(got)), out=at[1:])
            blob = np.frombuffer("".join(got).encode("ascii"), np.uint8)  # a float's text is ASCII: one byte a character
            first = 0
            for i in which:
                end = first + done[i][2].size
                texts[i] = blob[at[first]:at[end]], at[first:end + 1] - at[first]
                first = end
    # a side's work is its formatted values (a copied tuple's text is one block copy, counted at
    # a fiftieth of a formatted value's)
    work = [(d[0].size - int(np.count_nonzero(d[3])) * (d[0].size // max(d[0].shape[0], 1))) + d[0].size // 50 for d in done]
    sides = _sides(chains, work, both)
    out: list = [None] * len(done)
    _run_sides(both, [lambda side=side: _formatted(done, texts, refs, out, side) for side in sides])
    return out


def _chains(refs: list) -> list[list[int]]:
    """The indices of the arrays linked by ``refs`` (``refs[i] < i``), each chain's in order,
    the chains in the order of their first array."""
    root = list(range(len(refs)))
    for i, j in enumerate(refs):
        if j is not None and 0 <= j < i:
            root[i] = root[j]
    chains: dict = {}
    for i, r in enumerate(root):
        chains.setdefault(r, []).append(i)
    return list(chains.values())


def _sides(chains: list[list[int]], work: list, both) -> list[list[int]]:
    """``chains`` dealt to two sides of about equal ``work`` (an array's), each side's indices in
    order: the heaviest chain first to the lighter side. One side (every index) without ``both``
    or where the lighter side would hold less than `SIDE_MIN`."""
    every = [i for chain in chains for i in chain]
    if both is None or len(chains) < 2:
        return [sorted(every)]
    weight = [sum(work[i] for i in chain) for chain in chains]
    load, dealt = [0, 0], [[], []]
    for c in sorted(range(len(chains)), key=lambda c: (-weight[c], c)):
        s = 0 if load[0] <= load[1] else 1
        load[s] += weight[c]
        dealt[s] += chains[c]
    if min(load) < SIDE_MIN:
        return [sorted(every)]
    return [sorted(d) for d in dealt]


def _run_sides(both, calls: list) -> None:
    """Each of ``calls`` (one or two), through ``both`` where there are two."""
    if len(calls) == 2:
        both(*calls)
    else:
        for call in calls:
            call()


def _found(arrays: list, refs: list, done: list, side: list[int]) -> None:
    """``done[i]`` for each ``i`` of ``side`` (in order, a chain's references before it): the
    array as float32 or float64, its digits (float64) or None (float32, formatted in one pass),
    the indices of its values left to ``hard``, and ``same``, its tuples whose bits are its
    reference's. A reference that cannot serve (another shape or type) is dropped from ``refs``."""
    for i in side:
        values = np.ascontiguousarray(arrays[i])
        j = refs[i]
        if values.dtype != np.float64:
            values = values.astype(np.float32, copy=False)
        if j is not None and not (0 <= j < i and done[j][0].shape == values.shape and values.dtype == done[j][0].dtype == np.float32):
            j = refs[i] = None
        flat = values.reshape(-1).view(np.uint64 if values.dtype == np.float64 else np.uint32)
        same = np.zeros(values.shape[0] if j is not None else 0, np.bool_)
        if values.dtype == np.float64 or values.shape[1] == 0:
            cs, ks, st = shortest_digits64(flat) if values.dtype == np.float64 else shortest_digits(flat, flat[:0], same)
            done[i] = (values, (cs, ks, st), np.flatnonzero(st == 2), same)
        else:  # float32: only the values the kernel hands back are found here, their text is written in one pass
            done[i] = (values, None, _marks(flat, values.shape[1], done[j][0].reshape(-1).view(np.uint32) if j is not None else flat[:0], same),
                       same)


def _formatted(done: list, texts: list, refs: list, out: list, side: list[int]) -> None:
    """``out[i]``, the text of each ``i`` of ``side`` (in order), from `_found`'s ``done[i]``,
    its values' texts from ``hard`` (``texts[i]``) and its reference's text."""
    # a text and its tuple starts are kept while a later array of the side refers to it
    last_use = {refs[i]: i for i in side if refs[i] is not None}
    starts: dict = {}
    empty = np.frombuffer(b"", np.uint8), np.zeros(1, np.int64)
    for i in side:
        values, digits, _, same = done[i]  # the values left to ``hard`` come formatted in texts[i]
        hard_bytes, hard_at = texts[i]
        j = refs[i]
        ref_text, ref_at = starts[j] if j is not None else empty
        buf = np.empty(_tuples_bound(values, hard_bytes, ref_text), np.uint8)
        if digits is None:
            size, at = _float32_text(values.reshape(-1).view(np.uint32), values.shape[1], same, hard_bytes, hard_at, ref_text, ref_at, buf)
        else:
            size, at = _tuples_text(values.shape[0], values.shape[1], np.signbit(values.reshape(-1)), *digits,
                                    hard_bytes, hard_at, same, ref_text, ref_at, buf)
        text = _trimmed(buf, size)
        text.flags.writeable = False  # read-only, as the other bytes arrays the kernels take
        out[i] = text
        if last_use.get(i, -1) > i:
            starts[i] = text, at
        if j is not None and last_use[j] == i:
            del starts[j]


@njit(cache=True, nogil=True)
def _ints_text(values, m):
    """``[a, b, ...]`` (``m`` 0) or ``[(a, b), ...]`` (tuples of ``m``) of int32 ``values``."""
    n = values.shape[0]
    buf = np.empty(2 + n * 15, np.uint8)  # sign, 10 digits, ", " and parentheses
    buf[0] = 91
    at = 1
    for i in range(n):
        first = m == 0 or i % m == 0
        if i > 0:
            if first and m > 0:
                buf[at] = 41  # ')'
                at += 1
            buf[at] = 44
            buf[at + 1] = 32
            at += 2
        if first and m > 0:
            buf[at] = 40  # '('
            at += 1
        v = np.int64(values[i])
        if v < 0:
            buf[at] = 45
            at += 1
            v = -v
        at = _put_digits(buf, at, v, _ndigits(v), 0)
    if n > 0 and m > 0:
        buf[at] = 41
        at += 1
    buf[at] = 93
    return buf[:at + 1]


def ints_text(values: np.ndarray) -> bytes:
    """The text of int32 ``values``: ``[a, b, ...]`` for ``(n,)``, ``[(a, b), ...]`` for ``(n, m)``."""
    values = np.asarray(values)
    m = values.shape[1] if values.ndim == 2 else 0
    flat = np.ascontiguousarray(values, dtype=np.int32).reshape(-1)
    if flat.flags.writeable:  # one specialisation: USD's buffers come read-only, numpy's copies not
        flat = flat.view()
        flat.flags.writeable = False
    return _ints_text(flat, m).tobytes()
