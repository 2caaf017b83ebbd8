"""Compiled evaluation of an H-spline surface and its partial derivatives, point by point.

`eval_points` computes the sum of `acra.hspline`'s module docstring,

    Q(u, v) = Q0(u, v) + sum_{k visited} sum_{a,b} B_a(t_u^k) B_b(t_v^k) · D_k[rows_k(pu, pv)[a, b]]

for each point on its own: the level-0 segment and the 4×4 block of level-0 CVs under it, then
for each finer level that `HSpline._terms_index` visits, the point's level-``k`` segment, a binary
search of that level's active patch keys for it, and (where the patch is active) its 4×4 block of
detail vectors ``D_k`` weighted by the level-``k`` basis functions. Derivatives are with respect
to level-0 ``u, v``: the order-``o`` basis row of level ``k`` is scaled by ``2**(k o)``.

Segments, clamping, wrap and the ``side`` convention are those of `acra.hspline._segments_all`;
basis values are `acra.basis.basis_rows`'s formulas; each level's term is contracted over ``b``
then ``a`` and added to the point's sum in level order, as `acra.hspline._evaluate_numpy` does,
so results agree with it to rounding (measured: 1.4e-16 of the object's size for points,
4e-15 for second derivatives).

A level's v contraction ``sum_b B_b(t_v^k) D_k[a, b]`` depends on v and the block alone, so a
point on the same v (bit for bit) and block as the point before takes the one computed then: the
same products summed in the same order, so every bit is what a call of that point alone gives
(`tests/test_kernels.py`). A display's points come sorted by ``(u, v)``; `acra.tessellate.grid_samples`
passes them by v, then u, where consecutive points share v and, on each level, mostly the block
(85-89 % of the demo's terms a round), and the rounds' display evaluations cost about 40 % less
(their calls replayed: 3.8 against 2.2 ms CPU a frame). In (u, v) order nothing is shared, and
the checks cost about 4 %.

Why compiled: the array form gathers every (point, level) term's 4×4 CV block with `np.take`
and pays a few dozen numpy calls per call. On the demo head after a response (7 levels), the
23,491-point display took 44 ms (points) and 68 ms (with first derivatives) that way against
5.1 and 7.4 ms here, and a call of 50 points 0.125 ms, nearly all of it per-call overhead,
against 0.015 ms (`benchmarks/eval_kernel.py`; `docs/performance.md`, *Compiled evaluation*).
The compiled code is cached on disk (``cache=True``: ``__pycache__`` beside this file): a fresh
process loads it in ~7 ms after numba's own import and set-up (~0.6 s); with an empty cache,
the first call compiles it (~3 s).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from acra.framekernels import cross_test

__all__ = ["eval_points", "NSLOTS", "mark_cells", "changed_level", "ascending", "place_normals"]

# output slots per derivative order: (0,0) | (1,0) (0,1) | (2,0) (1,1) (0,2), as `SurfaceEval`'s fields
NSLOTS = (1, 3, 6)
_NSLOT = np.array(NSLOTS, np.int64)
_SLOT_P = np.array([0, 1, 0, 2, 1, 0], np.int64)  # derivative order along u of each slot
_SLOT_Q = np.array([0, 0, 1, 0, 1, 2], np.int64)  # and along v


@njit(inline="always")
def _domain(x, patches0, periodic):
    """``x`` (level-0 units) brought into the domain ``[0, P0]``: ``np.mod(x, P0)`` (numpy's
    ``fmod`` and sign fix) along a periodic direction, ``np.clip(x, 0, P0)`` along an open one;
    NaN for a NaN ``x`` and an infinite periodic one. Scaling by ``2**k`` is exact, so this times
    ``2**k`` is what `acra.hspline._segments_all` wraps or clamps ``x * 2**k`` to at level ``k``."""
    n = float(patches0)
    if periodic:
        if 0.0 < x < n:  # fmod's exact result there, without its cost
            return x
        r = np.fmod(x, n)
        if r != 0.0:
            if r < 0.0:
                r += n
        else:
            r = 0.0
        return r
    if x != x:
        return x
    return min(max(x, 0.0), n)


@njit(inline="always")
def _segment(x0, k, patches0, periodic, side):
    """Level-``k`` segment and local parameter of ``x0`` (`_domain`'s, not NaN): the domain's end
    belongs to the last segment; ``side < 0`` moves a point on an interior knot to the segment
    on its left."""
    count = patches0 << k
    xs = x0 * float(1 << k)
    seg = min(int(math.floor(xs)), count - 1)  # np.mod can round up to count
    t = xs - seg
    if side < 0 and t == 0.0 and (seg > 0 or periodic):
        seg -= 1
        if seg < 0:
            seg += count
        t = 1.0
    return seg, t


@njit(inline="always")
def _basis(t, scale, order, out):
    """Write the uniform cubic B-spline rows of derivative orders ``0..order`` at ``t`` into
    ``out (3, 4) float64``, order ``o`` multiplied by ``scale**o`` (d/dx = 2**k d/dt)."""
    s = 1.0 - t
    out[0, 0] = s * s * s / 6.0
    out[0, 1] = ((3.0 * t - 6.0) * t * t + 4.0) / 6.0
    out[0, 2] = ((3.0 * s - 6.0) * s * s + 4.0) / 6.0
    out[0, 3] = t * t * t / 6.0
    if order >= 1:
        # powers' derivative (0, 1, 2t, 3t²) times `basis._COEF` rows
        p2, p3 = 2.0 * t, 3.0 * t * t
        out[1, 0] = (-3.0 / 6.0 + (3.0 / 6.0) * p2) + (-1.0 / 6.0) * p3
        out[1, 1] = (-6.0 / 6.0) * p2 + (3.0 / 6.0) * p3
        out[1, 2] = (3.0 / 6.0 + (3.0 / 6.0) * p2) + (-3.0 / 6.0) * p3
        out[1, 3] = (1.0 / 6.0) * p3
        for i in range(4):
            out[1, i] *= scale
    if order >= 2:
        # second derivative of the powers: (0, 0, 2, 6t)
        p3 = 6.0 * t
        s2 = scale * scale
        out[2, 0] = ((3.0 / 6.0) * 2.0 + (-1.0 / 6.0) * p3) * s2
        out[2, 1] = ((-6.0 / 6.0) * 2.0 + (3.0 / 6.0) * p3) * s2
        out[2, 2] = ((3.0 / 6.0) * 2.0 + (-3.0 / 6.0) * p3) * s2
        out[2, 3] = ((1.0 / 6.0) * p3) * s2


@njit(inline="always")
def _same(x, y):
    """``x`` and ``y`` hold the same float, the sign of a zero included (a basis row at -0.0 and
    at 0.0 can differ in the signs of its zeros)."""
    return x == y and math.copysign(1.0, x) == math.copysign(1.0, y)


@njit(inline="always")
def _half(rv, order, table, rows, base, half):
    """The v contraction of one 4×4 block: ``half[a, q, c] = sum_b rv[q, b] · block[a, b, c]``.

    ``rv (3, 4) float64``: basis rows along v (`_basis`); ``table (r, 3) float64`` with the
    block's rows ``rows (4, 4) int64`` (entry ``[a, b]`` is CV ``(a, b)`` of the block, row
    ``rows[a, b] - base`` of ``table``); ``half (4, 3, 3) float64`` written. It reads neither u
    nor the point's sum, so points that share v (bit for bit) and the block share it."""
    for a in range(4):
        r0, r1, r2, r3 = rows[a, 0] - base, rows[a, 1] - base, rows[a, 2] - base, rows[a, 3] - base
        for q in range(order + 1):
            w0, w1, w2, w3 = rv[q, 0], rv[q, 1], rv[q, 2], rv[q, 3]
            for c in range(3):
                half[a, q, c] = w0 * table[r0, c] + w1 * table[r1, c] + w2 * table[r2, c] + w3 * table[r3, c]


@njit(inline="always")
def _add_term(ru, order, half, sum_):
    """Add one block's term to a point's sum: slot ``(p, q)`` is ``sum_a ru[p, a] · half[a, q]``
    (``ru (3, 4) float64`` the basis rows along u, ``half (4, 3, 3)`` `_half`'s, ``sum_ (6, 3)
    float64`` the point's running sum per slot)."""
    for s in range(_NSLOT[order]):
        p, q = _SLOT_P[s], _SLOT_Q[s]
        w0, w1, w2, w3 = ru[p, 0], ru[p, 1], ru[p, 2], ru[p, 3]
        for c in range(3):
            sum_[s, c] += w0 * half[0, q, c] + w1 * half[1, q, c] + w2 * half[2, q, c] + w3 * half[3, q, c]


@njit(cache=True, nogil=True)
def eval_points(u, v, order, side, top, nu, u_periodic, nv, v_periodic, cvs,
                levels, keys, shifts, ends, patch_rows, table_rows, table, out):
    """Points and partial derivatives of an H-spline at ``(u[i], v[i])``, written to ``out``.

    Parameters
    ----------
    u, v : (m,) float64
        Parameters in level-0 patch units.
    order : int
        0, 1 or 2: the derivative orders wanted (``NSLOTS[order]`` output slots).
    side : int
        ``< 0``: a point on an interior knot takes the segment on its left; else the right.
    top : int
        Finest level summed (``upto``, at most ``depth - 1``).
    nu, nv : int
        Level-0 CV counts along u and v; ``u_periodic, v_periodic`` (bool) their wrap.
    cvs : (nu * nv, 3) float64
        Level-0 CVs, row ``iu * nv + iv``.
    levels : (L,) int64
        The visited levels, ascending, 0 first (`HSpline._terms_index`).
    keys : (p,) int64
        Every visited fine level's active patch keys ``pu * Pv_k + pv`` plus that level's shift,
        sorted.
    shifts, ends : (L - 1,) int64
        Per visited fine level: its key shift, and where its keys end in ``keys``.
    patch_rows : (p, 4, 4) int64
        Each active patch's CV block as rows of ``[cvs; table]``.
    table_rows : (depth,) int64
        Rows of ``[cvs; table]`` through each level (`HSpline._table_rows`).
    table : (r, 3) float64
        Detail vectors of levels ``1, 2, ...``, stacked (`Details.table`); ``ValueError`` if it
        ends before a summed level's rows do.
    out : (NSLOTS[order], m, 3) float64
        Written: slot ``s`` of point ``i`` is ``out[s, i]``. A point with a NaN parameter gets NaN.
    """
    m = u.shape[0]
    p0u = nu if u_periodic else nu - 3
    p0v = nv if v_periodic else nv - 3
    nslot = 1 if order == 0 else (3 if order == 1 else 6)
    nlev = 0
    while nlev < levels.shape[0] and levels[nlev] <= top:
        nlev += 1
    base = table_rows[0]
    if nlev > 1 and base + table.shape[0] < table_rows[levels[nlev - 1]]:
        raise ValueError("the detail table is shorter than the levels evaluated need")
    ru = np.zeros((3, 4))  # (order, CV) float64: basis rows along u of the current level
    rv = np.zeros((3, 4))  # and along v
    sum_ = np.zeros((6, 3))  # (slot, xyz) float64: the current point's sum
    # (level, a, q, xyz) float64: per visited level, the v contraction of the last block summed
    # (`_half`), kept with the v and block it was taken for: a point with the same v (bit for bit)
    # on the same block reuses it, the same products in the same order
    half = np.zeros((max(nlev, 1), 4, 3, 3))
    half_v = np.full(max(nlev, 1), np.nan)  # (nlev,) float64: the v of each level's `half`
    half_block = np.full(max(nlev, 1), -1, np.int64)  # (nlev,) int64: and its block (level 0: su; else the patch row)
    rows0 = np.empty((4, 4), np.int64)  # (a, b) int64: the point's level-0 block, rows of `cvs`
    last_key = np.full(nlev, -1, np.int64)  # (nlev,) int64 per level: the last key looked up
    last_row = np.full(nlev, -1, np.int64)  # (nlev,) int64: its row in `keys` (-1: not active)
    last_pos = np.zeros(nlev, np.int64)  # (nlev,) int64: the first row of `keys` holding a key >= it
    seg_v = np.empty(nlev, np.int64)  # (nlev,) int64 per level: the last point's segment along v
    t_v = np.empty(nlev)  # (nlev,) float64: and its local parameter
    last_v = np.nan  # that point's v (`_domain`'s)
    for i in range(m):
        u0 = _domain(u[i], p0u, u_periodic)
        v0 = _domain(v[i], p0v, v_periodic)
        if u0 != u0 or v0 != v0:
            for s in range(nslot):
                for c in range(3):
                    out[s, i, c] = np.nan
            continue
        new_v = not _same(v0, last_v)
        last_v = v0
        su, tu = _segment(u0, 0, p0u, u_periodic, side)
        for s in range(nslot):
            for c in range(3):
                sum_[s, c] = -0.0  # -0.0 + x is x, the sign of a zero included
        _basis(tu, 1.0, order, ru)
        if not (half_block[0] == su and _same(v0, half_v[0])):
            sv, tv = _segment(v0, 0, p0v, v_periodic, side)
            for a in range(4):
                iu = su + a
                if u_periodic and iu >= nu:
                    iu -= nu
                for b in range(4):
                    iv = sv + b
                    if v_periodic and iv >= nv:
                        iv -= nv
                    rows0[a, b] = iu * nv + iv
            _basis(tv, 1.0, order, rv)
            _half(rv, order, cvs, rows0, 0, half[0])
            half_v[0], half_block[0] = v0, su
        _add_term(ru, order, half[0], sum_)
        for lv in range(1, nlev):
            k = levels[lv]
            su, tu = _segment(u0, k, p0u, u_periodic, side)
            if new_v:
                seg_v[lv], t_v[lv] = _segment(v0, k, p0v, v_periodic, side)
            sv, tv = seg_v[lv], t_v[lv]
            want = su * (p0v << k) + sv + shifts[lv - 1]
            if want == last_key[lv]:  # the previous point's patch on this level
                lo = last_row[lv]
            else:
                lo = 0 if lv == 1 else ends[lv - 2]
                hi = ends[lv - 1]
                if want > last_key[lv] >= 0:
                    # the points come by v, then u: the next patch along u lies a little after the
                    # last one's place, so gallop from there before bisecting
                    lo = last_pos[lv]
                    step = 1
                    while lo + step < hi and keys[lo + step] < want:
                        lo += step
                        step <<= 1
                    hi = min(lo + step, hi)
                while lo < hi:  # first key >= want in this level's keys
                    mid = (lo + hi) >> 1
                    if keys[mid] < want:
                        lo = mid + 1
                    else:
                        hi = mid
                last_pos[lv] = lo
                if lo == ends[lv - 1] or keys[lo] != want:
                    lo = -1
                last_key[lv] = want
                last_row[lv] = lo
            if lo < 0:
                continue
            scale = float(1 << k)
            _basis(tu, scale, order, ru)
            if not (half_block[lv] == lo and _same(v0, half_v[lv])):
                _basis(tv, scale, order, rv)
                _half(rv, order, table, patch_rows[lo], base, half[lv])
                half_v[lv], half_block[lv] = v0, lo
            _add_term(ru, order, half[lv], sum_)
        for s in range(nslot):
            for c in range(3):
                out[s, i, c] = sum_[s, c]


@njit(inline="always")
def _patch_index(q, n, periodic):
    """Patch ``q`` of a direction with ``n`` patches: wrapped if ``periodic``, else clipped to
    ``0..n - 1``."""
    return q % n if periodic else min(max(q, 0), n - 1)


@njit(inline="always")
def _mark_one(out, pu, pv, k, level, spread, nu_k, nv_k, u_periodic, v_periodic):
    """`mark_cells` of one level-``k`` patch or CV ``(pu, pv)``."""
    r = 1 << (level - k) if level > k else 1
    shift = k - level if k > level else 0
    for d in range(spread + 1):
        qu = _patch_index(pu - spread + d, nu_k, u_periodic)
        for e in range(spread + 1):
            qv = _patch_index(pv - spread + e, nv_k, v_periodic)
            if r == 1:
                out[qu >> shift, qv >> shift] = True
            else:
                for a in range(r):
                    for b in range(r):
                        out[qu * r + a, qv * r + b] = True


@njit(cache=True, nogil=True)
def mark_cells(out, pu, pv, k, level, spread, nu_k, nv_k, u_periodic, v_periodic):
    """Set in ``out (P0u << level, P0v << level) bool`` every level-``level`` cell that holds a
    level-``k`` patch ``(pu[i] - d, pv[i] - e)`` for ``d, e`` in ``0..spread`` (``pu, pv (m,)
    int64``; ``spread`` 3: the patches a level-``k`` CV ``(pu[i], pv[i])`` supports, 0: the
    patches themselves), wrapped along a periodic direction and clipped to ``0..n_k - 1`` along
    an open one (``nu_k, nv_k``: level ``k``'s patch counts). A coarser patch covers a block of
    cells, a finer one lies in one. `acra.hspline.changed_cells`' marking, as numpy's index
    assignments it replaces would set them, without their per-level array set-up."""
    for i in range(pu.shape[0]):
        _mark_one(out, pu[i], pv[i], k, level, spread, nu_k, nv_k, u_periodic, v_periodic)


@njit(cache=True, nogil=True)
def ascending(keys):
    """Whether ``keys (m,)`` are strictly ascending (`changed_level`'s merges and
    `acra.levelkernels.build_level` need sorted keys)."""
    for i in range(1, keys.shape[0]):
        if keys[i] <= keys[i - 1]:
            return False
    return True


@njit(cache=True, nogil=True)
def changed_level(out, k, level, pa, pb, a_keys, b_keys, va, vb, npv_k, ncv_k, nu_k, nv_k, u_periodic, v_periodic):
    """`acra.hspline.changed_cells`' level ``k`` in one pass: marks in ``out`` (`mark_cells`) each
    level-``k`` patch active on one surface alone (``pa``, ``pb (m,) int64``: the old and new
    surfaces' active patch keys ``pu * npv_k + pv`` where `evaluate` visits the level, else
    empty) and the patches each level-``k`` CV supports whose detail vector differs: on one
    surface alone (``a_keys``, ``b_keys``: their CV keys ``ju * ncv_k + jv``), or whose bits
    ``va``, ``vb (m, 3) int64`` (the detail vectors' float64 bits, row by key) differ. Each pair
    of key lists is merged, so every list must ascend strictly: returns False, having marked
    nothing, where one does not (the caller takes numpy's set operations instead)."""
    if not (ascending(pa) and ascending(pb) and ascending(a_keys) and ascending(b_keys)):
        return False
    # what to mark, gathered by both merges and marked in one loop (one copy of the marking)
    at = np.empty(pa.shape[0] + pb.shape[0] + a_keys.shape[0] + b_keys.shape[0], np.int64)
    m = 0
    for lists in range(2):
        xa, xb = (pa, pb) if lists == 0 else (a_keys, b_keys)
        i, j = 0, 0
        while i < xa.shape[0] or j < xb.shape[0]:
            if j == xb.shape[0] or (i < xa.shape[0] and xa[i] < xb[j]):
                at[m] = xa[i]
                i += 1
            elif i == xa.shape[0] or xb[j] < xa[i]:
                at[m] = xb[j]
                j += 1
            else:
                same = lists == 0 or (va[i, 0] == vb[j, 0] and va[i, 1] == vb[j, 1] and va[i, 2] == vb[j, 2])
                at[m] = xb[j]
                i += 1
                j += 1
                if same:
                    continue
            m += 1
        if lists == 0:
            patches = m
    for q in range(m):
        if q < patches:
            pu, pv, spread = at[q] // npv_k, at[q] % npv_k, 0
        else:
            pu, pv, spread = at[q] // ncv_k, at[q] % ncv_k, 3
        _mark_one(out, pu, pv, k, level, spread, nu_k, nv_k, u_periodic, v_periodic)
    return True


@njit(inline="always")
def _tangent_normal(a0, a1, a2, b0, b1, b2, quick, c1, c2, c1s, c2s):
    """One row of `place_normals`: the unit normal ``(n0, n1, n2)`` of ``du = (a0, a1, a2)``,
    ``dv = (b0, b1, b2)`` and whether it has no direction (then the normal is unset), with
    ``quick`` (``c2 >= 1e-100``), ``c1s = c1 * c1`` and ``c2s = c2 * c2`` taken once a call."""
    if quick:
        n0 = a1 * b2 - a2 * b1
        n1 = a2 * b0 - a0 * b2
        n2 = a0 * b1 - a1 * b0
        nn = (n0 * n0 + n1 * n1) + n2 * n2
        la2 = (a0 * a0 + a1 * a1) + a2 * a2
        lb2 = (b0 * b0 + b1 * b1) + b2 * b2
        if nn > 4.0 * (c1s * max(la2, lb2) + c2s):  # false for a NaN or an overflow
            length = math.sqrt(nn)
            return n0 / length, n1 / length, n2 / length, False
    n0, n1, n2, length, bad = cross_test(a0, a1, a2, b0, b1, b2, c1, c2)
    if bad:
        return 0.0, 0.0, 0.0, True
    return n0 / length, n1 / length, n2 / length, False


@njit(cache=True, nogil=True)
def place_normals(p, du, dv, rows, c1, c2, points, limit, bad):
    """An evaluation's points ``p`` and first derivatives ``du``, ``dv`` (each ``(m, 3)
    float64``) written into a display: each point into ``points``' row ``rows[i]`` (``rows (m,)
    int64``) and its unit normal into ``limit``'s (both ``(n, 3) float64``): ``du × dv`` over its
    length, the products, test and quotient of `acra.framekernels.degenerate` and `unit_rows` (so
    `acra.hspline.surface_normals`' bits). ``bad (m,) bool`` marks the rows where ``|du × dv| <=
    c1 max(|du|, |dv|) + c2`` (no direction), whose ``limit`` row is left for the caller's limit
    normals. Returns how many are bad. One pass, without stacking ``du`` and ``dv`` or an array
    of the normals.

    A row whose ``|du × dv|²`` exceeds ``4 (c1² max(|du|², |dv|²) + c2²)`` passes the test
    whatever the rounding (``(c1 L + c2)² <= 2 (c1² L² + c2²)``, and the factor 2 left covers
    every rounding by far), so it takes one square root instead of three; the others take the
    test itself. Where ``c2²`` could underflow (``c2 < 1e-100``) every row takes the test."""
    count = 0
    quick = c2 >= 1e-100
    c1s, c2s = c1 * c1, c2 * c2
    for i in range(rows.shape[0]):
        r = rows[i]
        points[r, 0], points[r, 1], points[r, 2] = p[i, 0], p[i, 1], p[i, 2]
        n0, n1, n2, b = _tangent_normal(du[i, 0], du[i, 1], du[i, 2], dv[i, 0], dv[i, 1], dv[i, 2],
                                        quick, c1, c2, c1s, c2s)
        bad[i] = b
        if b:
            count += 1
        else:
            limit[r, 0], limit[r, 1], limit[r, 2] = n0, n1, n2
    return count
