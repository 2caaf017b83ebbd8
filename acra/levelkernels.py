"""Compiled bookkeeping of hierarchy levels: building one (`acra.hierarchy._build_level`) and
the CVs a data point weighs on one (`acra.interpolate._entries`).

A refinement rebuilds the level it adds patches to: the sorted active patch keys, the CV keys
of their 4×4 blocks, each block's rows, the C2 movability of every CV (all existing patches of
its support active) and the offsets the old level had. In array form that is some thirty numpy
calls on a few hundred to a few thousand keys (sorts, `np.unique`, `np.searchsorted` of
unsorted keys), and a response refines up to three levels a step (`hierarchy.make_movable`);
here it is one pass. Everything is integer bookkeeping plus a copy of the old offsets, so the
level is the same as the array form's, key for key (`tests/test_hspline.py` holds it to it).
The patches a response refines on a level, the 7×7 block about each data point's patch and
the parents of the finer level's, are listed by `block_keys`.
Following a response's move down the levels (`acra.details.moved_details`), which rows of a
level changed bits (`differing_rows`), each level's frames and vectors restated on the rows
that moved or whose frames turned, with the level-0 patches the changed vectors' CVs support
(`restate_rows`; `mark_changed`), and which finer CVs' frames lie on those patches or rings
(`stale_rows`) are each one pass in place of a dozen numpy calls on a few hundred rows.
What the frames of a level need of its movable CVs (`acra.details._movable_places`: their
indices, Greville centres and level-0 patches) is `movable_places`, one pass over the level.
The CVs a level's data points weigh, and the patches its additional points fall in, are
numbered by `unique_inverse` (`np.unique` with ``return_inverse``, a sort of a few hundred
integers at most). A data point's weights are its basis rows' products, each one multiplication as numpy's
broadcast product, so they too are the array form's bits (`tests/test_interpolate.py`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from acra.kernels import ascending, mark_cells

__all__ = ["build_level", "block_keys", "point_entries", "unique_inverse", "movable_places", "differing_rows",
           "mark_changed", "restate_rows", "stale_rows", "merge_points"]


_MAX_CELLS = 1 << 22  # largest level grid the dense marks are used for (4 M cells, ~40 MB)


@njit(cache=True, nogil=True)
def _find(sorted_keys, key):
    """``np.searchsorted(sorted_keys, key)`` clipped to the last row, and whether it is ``key``."""
    lo, hi = 0, sorted_keys.shape[0]
    while lo < hi:
        mid = (lo + hi) >> 1
        if sorted_keys[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    if lo > sorted_keys.shape[0] - 1:
        lo = sorted_keys.shape[0] - 1
    return lo, lo >= 0 and sorted_keys[lo] == key


@njit(cache=True, nogil=True)
def _wrap(j, count, periodic):
    return j % count if periodic else j  # Python's (and np.mod's) sign of the result


@njit(cache=True, nogil=True)
def _sort(a):
    """``a`` sorted in place (Shell's sort, Knuth's gaps): a few thousand keys at most, and
    numba's ``np.sort`` costs seconds to compile."""
    gap = 1
    while gap < a.shape[0] // 3:
        gap = 3 * gap + 1
    while gap >= 1:
        for i in range(gap, a.shape[0]):
            x = a[i]
            j = i
            while j >= gap and a[j - gap] > x:
                a[j] = a[j - gap]
                j -= gap
            a[j] = x
        gap //= 3
    return a


@njit(cache=True, nogil=True)
def unique_inverse(x):
    """``np.unique(x, return_inverse=True)`` of ``x (n,) int64``: the sorted distinct values
    ``(m,) int64`` and the place of each entry among them ``(n,) int64``. Integers, so the same
    values as numpy's; numpy's costs tens of microseconds of set-up on the few hundred entries of
    a level's solve (`acra.interpolate.point_weights`, `acra.targets.patch_groups`)."""
    n = x.shape[0]
    if n:
        lo = hi = x[0]  # loops, here and below: numba's array min and max cost seconds to compile
        for i in range(1, n):
            if x[i] < lo:
                lo = x[i]
            elif x[i] > hi:
                hi = x[i]
        # a level's rows and patch keys span a few times their count at most: marking the span
        # is linear where the sort is not (a pole's entries repeat each ring CV per point, some
        # thousands of entries on two hundred rows); a far-flung key (a NaN parameter's) sorts
        if lo > -(1 << 62) and hi < (1 << 62) and hi - lo < 8 * n + 4096:
            place = np.zeros(hi - lo + 1, np.int64)  # each value marked, then numbered in order
            for i in range(n):
                place[x[i] - lo] = 1
            m = 0
            for r in range(place.shape[0]):
                if place[r]:
                    place[r] = m
                    m += 1
                else:
                    place[r] = -1
            uniq = np.empty(m, np.int64)
            for r in range(place.shape[0]):
                if place[r] >= 0:
                    uniq[place[r]] = r + lo
            inverse = np.empty(n, np.int64)
            for i in range(n):
                inverse[i] = place[x[i] - lo]
            return uniq, inverse
    uniq = _sort(x.copy())
    m = 0
    for i in range(n):
        if m == 0 or uniq[i] != uniq[m - 1]:
            uniq[m] = uniq[i]
            m += 1
    uniq = uniq[:m].copy()
    inverse = np.empty(n, np.int64)
    for i in range(n):
        inverse[i] = _find(uniq, x[i])[0]
    return uniq, inverse


@njit(cache=True, nogil=True)
def _merge(old, fresh):
    """Sorted union of strictly increasing ``old`` and sorted ``fresh`` that has no key of ``old``."""
    out = np.empty(old.shape[0] + fresh.shape[0], np.int64)
    i = j = 0
    for n in range(out.shape[0]):
        if j == fresh.shape[0] or (i < old.shape[0] and old[i] < fresh[j]):
            out[n] = old[i]
            i += 1
        else:
            out[n] = fresh[j]
            j += 1
    return out


@njit(cache=True, nogil=True)
def build_level(keys, old_patches, old_cv_keys, old_offsets,
                u_cvs, u_patches, u_periodic, v_cvs, v_patches, v_periodic):
    """Level ``k`` with ``old_patches`` plus the patch keys ``keys (n,) int64`` (in range, any
    order, repeats) active, from the old level's ``old_patches``, ``old_cv_keys`` (both strictly
    increasing) and ``old_offsets``; ``*_cvs``, ``*_patches``: the level's CV and patch counts
    along u and v (at most `_MAX_CELLS` of each).

    Returns ``status`` (0: built; 1: every key already active, nothing built; 2: an old key
    array not strictly increasing, nothing built), ``patches (m,)``, ``cv_keys (c,)``,
    ``patch_rows (m, 4, 4)``, ``movable (c,) bool``, ``offsets (c, 3)`` and whether an old
    offset sits on a CV that is not movable. The arrays are `_build_level_numpy`'s:
    ``np.unique`` of the patches; the old CVs (if the level had patches) and the new patches'
    blocks' CVs, sorted; C2 movability; the offsets of the old CVs that stay."""
    none = np.zeros(0, np.int64)
    if not (ascending(old_patches) and ascending(old_cv_keys)):
        return 2, none, none, np.zeros((0, 4, 4), np.int64), np.zeros(0, np.bool_), np.zeros((0, 3)), False
    active = np.zeros(u_patches * v_patches, np.bool_)
    for p in old_patches:
        active[p] = True
    fresh = np.empty(keys.shape[0], np.int64)
    nf = 0
    for p in keys:
        if not active[p]:
            active[p] = True
            fresh[nf] = p
            nf += 1
    if nf == 0:
        return 1, none, none, np.zeros((0, 4, 4), np.int64), np.zeros(0, np.bool_), np.zeros((0, 3)), False
    fresh = _sort(fresh[:nf])
    patches = _merge(old_patches, fresh)
    # CVs: the old level's (its patches' blocks) and the new patches' blocks
    present = np.zeros(u_cvs * v_cvs, np.bool_)
    if old_patches.shape[0]:
        for q in old_cv_keys:
            present[q] = True
    added = np.empty(16 * nf, np.int64)
    na = 0
    for i in range(nf):
        pu, pv = fresh[i] // v_patches, fresh[i] % v_patches
        for a in range(4):
            ju = _wrap(pu + a, u_cvs, u_periodic)
            for b in range(4):
                q = ju * v_cvs + _wrap(pv + b, v_cvs, v_periodic)
                if not present[q]:
                    present[q] = True
                    added[na] = q
                    na += 1
    added = _sort(added[:na])
    cv_keys = _merge(old_cv_keys, added) if old_patches.shape[0] else added
    row = np.empty(u_cvs * v_cvs, np.int64)  # read only where ``present``
    for r in range(cv_keys.shape[0]):
        row[cv_keys[r]] = r
    m = patches.shape[0]
    patch_rows = np.empty((m, 4, 4), np.int64)
    for i in range(m):
        pu, pv = patches[i] // v_patches, patches[i] % v_patches
        for a in range(4):
            ju = _wrap(pu + a, u_cvs, u_periodic)
            for b in range(4):
                patch_rows[i, a, b] = row[ju * v_cvs + _wrap(pv + b, v_cvs, v_periodic)]
    # movable: every existing patch of the support (ju-3..ju) x (jv-3..jv) active
    c = cv_keys.shape[0]
    movable = np.empty(c, np.bool_)
    for r in range(c):
        cu, cv = cv_keys[r] // v_cvs, cv_keys[r] % v_cvs
        ok = True
        for a in range(4):
            su = cu - 3 + a
            if not (u_periodic or (su >= 0 and su < u_patches)):
                continue
            su = _wrap(su, u_patches, u_periodic)
            for b in range(4):
                sv = cv - 3 + b
                if not (v_periodic or (sv >= 0 and sv < v_patches)):
                    continue
                if not active[su * v_patches + _wrap(sv, v_patches, v_periodic)]:
                    ok = False
        movable[r] = ok
    offsets = np.zeros((c, 3))
    stranded = False
    for r_old in range(old_cv_keys.shape[0]):
        q = old_cv_keys[r_old]
        if present[q]:
            r = row[q]
            for d in range(3):
                offsets[r, d] = old_offsets[r_old, d]
                if not movable[r] and old_offsets[r_old, d] != 0.0:
                    stranded = True
    return 0, patches, cv_keys, patch_rows, movable, offsets, stranded


@njit(cache=True, nogil=True)
def _segment(x, level, count, periodic):
    """`acra.basis.locate` of one parameter: level-``level`` segment and local parameter of the
    level-0 parameter ``x`` (``count``: the level's segments), in numpy's arithmetic."""
    xs = x * float(1 << level)
    if periodic:
        xs = xs % count
    if xs != xs:  # np.mod and np.clip keep a NaN; numpy casts it to the least int64
        return np.int64(-9223372036854775808), xs
    if not periodic:
        xs = min(max(xs, 0.0), float(count))
    seg = np.int64(math.floor(xs))
    if seg > count - 1:
        seg = count - 1
    return seg, xs - seg


@njit(cache=True, nogil=True)
def _blending_row(t, out, i):
    """``out[i] = B_0..B_3 (t)`` (`acra.basis._blending`'s factored forms, then the division)."""
    s = 1.0 - t
    out[i, 0] = s * s * s / 6.0
    out[i, 1] = ((3.0 * t - 6.0) * t * t + 4.0) / 6.0
    out[i, 2] = ((3.0 * s - 6.0) * s * s + 4.0) / 6.0
    out[i, 3] = t * t * t / 6.0


@njit(cache=True, nogil=True)
def point_entries(u, v, pole, level, u_cvs, u_periodic, v_cvs, v_periodic, u_patches, v_patches,
                  cv_keys, movable, patches, ring_rows, ring_w, ring_at, ring_use):
    """`acra.interpolate.point_weights`' entries of points ``u, v (K,) float64`` (level-0
    parameters) on the movable CVs of ``level``, in one pass: ``point, row, w`` of every nonzero
    weight and ``active (K,) bool``. ``pole (K,) int64``: `acra.hierarchy.pole_of` of the
    points, the closed end each sits on or -1.

    A point off a pole (``pole < 0``) weighs its level-``level`` patch's 16 CVs ``(a, b)`` in
    row-major order whose weight ``bu[a] * bv[b]`` is positive and that exist and are movable
    (level 0: every grid CV), on a patch that is active (level 0: every patch); its segments
    (`acra.basis.locate`) and basis rows ``bu, bv`` (`acra.basis.basis`) are taken here in
    numpy's arithmetic. Then, end by end, each point on that end's pole, in order, weighs the
    end's ring: ``ring_rows[ring_at[i]:ring_at[i + 1]] (3 N,) int64`` with ``ring_w`` of the same
    span (`acra.interpolate._ring_weights`), if ``ring_use[i]`` (the ring wholly movable). The
    caller numbers the rows (`unique_inverse`, called apart: a kernel that calls it links it in,
    which costs seconds of compilation on a fresh install)."""
    K = u.shape[0]
    su = np.empty(K, np.int64)
    sv = np.empty(K, np.int64)
    bu = np.empty((K, 4))
    bv = np.empty((K, 4))
    for i in range(K):
        su[i], t = _segment(u[i], level, u_patches, u_periodic)
        _blending_row(t, bu, i)
        sv[i], t = _segment(v[i], level, v_patches, v_periodic)
        _blending_row(t, bv, i)
    on = 0  # entries of the points on a pole, each its end's whole ring
    for i in range(K):
        if pole[i] >= 0 and ring_use[pole[i]]:
            on += ring_at[pole[i] + 1] - ring_at[pole[i]]
    point = np.empty(16 * K + on, np.int64)
    rows = np.empty(16 * K + on, np.int64)
    w = np.empty(16 * K + on)
    n = 0
    c = cv_keys.shape[0]
    for i in range(K):
        if pole[i] >= 0:
            continue
        if level and not _find(patches, su[i] * v_patches + sv[i])[1]:
            continue
        for a in range(4):
            ju = _wrap(su[i] + a, u_cvs, u_periodic)
            for b in range(4):
                x = bu[i, a] * bv[i, b]
                if not x > 0.0:
                    continue
                q = ju * v_cvs + _wrap(sv[i] + b, v_cvs, v_periodic)
                if level:
                    if c == 0:
                        continue
                    r, hit = _find(cv_keys, q)
                    if not (hit and movable[r]):
                        continue
                    q = r
                point[n], rows[n], w[n] = i, q, x
                n += 1
    for e in range(ring_use.shape[0]):
        if not ring_use[e]:
            continue
        for i in range(K):
            if pole[i] == e:
                for j in range(ring_at[e], ring_at[e + 1]):
                    point[n], rows[n], w[n] = i, ring_rows[j], ring_w[j]
                    n += 1
    active = np.zeros(K, np.bool_)
    for j in range(n):
        active[point[j]] = True
    return point[:n], rows[:n], w[:n], active


@njit(cache=True, nogil=True)
def movable_places(cv_keys, movable, k, u_cvs, v_cvs, u_patches0, u_periodic, v_patches0, v_periodic, ends):
    """Of the movable CVs of a level-``k`` level (``cv_keys (c,) int64``, ``movable (c,) bool``):
    their ``rows``, pole ring ``ring`` (the index of the last of ``ends (E, 2) int64``, closed ends
    ``(axis, end)``, whose three outermost CV rows hold the CV, else -1), CV indices ``ju, jv``,
    Greville centres ``gu = (ju - 1.0) / 2**k``, ``gv`` (level-0 units, exact) and the level-0
    patch each centre is in, ``pu * P0v + pv`` with ``pu = (ju - 1) >> k`` wrapped (periodic) or
    clamped (open); each ``(m,)``, in row order. The same integer and float operations as the
    array form (`acra.details._movable_places_numpy`)."""
    m = 0
    for r in range(cv_keys.shape[0]):
        if movable[r]:
            m += 1
    rows = np.empty(m, np.int64)
    ring = np.full(m, -1, np.int64)
    ju = np.empty(m, np.int64)
    jv = np.empty(m, np.int64)
    gu = np.empty(m)
    gv = np.empty(m)
    centre = np.empty(m, np.int64)
    scale = float(1 << k)
    i = 0
    for r in range(cv_keys.shape[0]):
        if not movable[r]:
            continue
        a, b = cv_keys[r] // v_cvs, cv_keys[r] % v_cvs
        rows[i], ju[i], jv[i] = r, a, b
        gu[i] = (a - 1.0) / scale
        gv[i] = (b - 1.0) / scale
        pu, pv = (a - 1) >> k, (b - 1) >> k
        pu = pu % u_patches0 if u_periodic else min(max(pu, 0), u_patches0 - 1)
        pv = pv % v_patches0 if v_periodic else min(max(pv, 0), v_patches0 - 1)
        centre[i] = pu * v_patches0 + pv
        for e in range(ends.shape[0]):
            j, count = (a, u_cvs) if ends[e, 0] == 0 else (b, v_cvs)
            lo = 0 if ends[e, 1] == 0 else count - 3
            if j >= lo and j <= lo + 2:
                ring[i] = e
        i += 1
    return rows, ring, ju, jv, gu, gv, centre


@njit(cache=True, nogil=True)
def block_keys(u, v, level, u_patches, u_periodic, v_patches, v_periodic, finer, finer_v_patches):
    """Level-``level`` patch keys ``(n,) int64`` (any order, repeats kept) to activate: the 7×7
    block ``(su - 3 .. su + 3) × (sv - 3 .. sv + 3)`` about the level patch ``su, sv``
    (`acra.basis.locate`) of each point ``u, v (K,) float64`` (level-0 units), those outside an
    open border dropped and the rest wrapped (`acra.hierarchy.make_movable`), then the parent
    ``(pu >> 1, pv >> 1)`` of each level-``level + 1`` key of ``finer (m,) int64`` (in range;
    ``finer_v_patches``: that level's patch count along v)."""
    K = u.shape[0]
    out = np.empty(49 * K + finer.shape[0], np.int64)
    n = 0
    for i in range(K):
        su = _segment(u[i], level, u_patches, u_periodic)[0]
        sv = _segment(v[i], level, v_patches, v_periodic)[0]
        for a in range(-3, 4):
            pu = su + a
            if not (u_periodic or (pu >= 0 and pu < u_patches)):
                continue
            pu = _wrap(pu, u_patches, u_periodic)
            for b in range(-3, 4):
                pv = sv + b
                if not (v_periodic or (pv >= 0 and pv < v_patches)):
                    continue
                out[n] = pu * v_patches + _wrap(pv, v_patches, v_periodic)
                n += 1
    for key in finer:
        out[n] = ((key // finer_v_patches) >> 1) * v_patches + ((key % finer_v_patches) >> 1)
        n += 1
    return out[:n]


@njit(cache=True, nogil=True)
def differing_rows(a, b, rows):
    """The ``rows (m,) int64`` whose three values differ between ``a`` and ``b`` ``(c, 3) int64``
    (float64 arrays' bits, so ``-0.0`` is told from ``0.0``), in their order:
    ``rows[np.any(a[rows] != b[rows], axis=-1)]``."""
    out = np.empty(rows.shape[0], np.int64)
    n = 0
    for i in range(rows.shape[0]):
        r = rows[i]
        if a[r, 0] != b[r, 0] or a[r, 1] != b[r, 1] or a[r, 2] != b[r, 2]:
            out[n] = r
            n += 1
    return out[:n]


@njit(cache=True, nogil=True)
def mark_changed(new, old, rows, cv_keys, v_cvs, k, u_patches, v_patches, u_periodic, v_periodic, stale):
    """Of a level-``k`` move's ``rows (m,) int64``, those whose detail vectors ``new`` and ``old``
    ``(c, 3) int64`` (bits) differ (`differing_rows`): mark in ``stale (P0u, P0v) bool`` the
    level-0 patches holding a level-``k`` patch such a CV (key ``cv_keys[row]``, ``ju * v_cvs +
    jv``) supports (`acra.kernels.mark_cells`, spread 3); returns how many differ."""
    changed = differing_rows(new, old, rows)
    if changed.shape[0]:
        ju = np.empty(changed.shape[0], np.int64)
        jv = np.empty(changed.shape[0], np.int64)
        for i in range(changed.shape[0]):
            key = cv_keys[changed[i]]
            ju[i] = key // v_cvs
            jv[i] = key - ju[i] * v_cvs
        # level and spread as int64 values, not literals: the one specialisation Python's calls use
        mark_cells(stale, ju, jv, k, np.int64(0), np.int64(3), u_patches, v_patches, u_periodic, v_periodic)
    return changed.shape[0]


@njit(cache=True, nogil=True)
def restate_rows(frames, new_frames, rows, offsets, vectors, moves, moved):
    """A level's frames and detail vectors after a move changed its offsets, or the surface under
    it its frames, on ``rows (m,) int64`` (`acra.details.moved_details`): a copy of ``frames (c,
    3, 3)`` with those rows' set to ``new_frames (m, 3, 3)`` (none given, ``(0, 3, 3)``:
    ``frames`` itself), and a copy of ``vectors (c, 3)`` with those rows' vectors ``frame @
    offset``, each summed from 0.0 as ``(p0 + p2) + p1``, as ``np.einsum("mij,mj->mi")`` sums
    three products. Returns ``frames, vectors``.

    With ``moves (m, 3) float64`` (none: ``(0, 3)``) the rows are a move's, each once
    (`acra.moves.move_level`): first ``moved (c, 3) float64``, a copy of ``offsets`` the
    caller made, takes on each row the offset plus ``frame.T @ move``, that product summed from
    0.0 in order ``p0, p1, p2`` as ``np.einsum("mji,mj->mi")`` sums it, added as numpy's
    ``offsets[rows] += ...`` adds it; then the vectors are restated from ``moved`` on the rows
    whose offsets changed bits (`differing_rows`', but a NaN offset counts as changed, which
    restates its row with the bits it had), the others' kept. (It calls no other kernel:
    a compiled call compiles its callee again into the caller, seconds on a fresh install.)"""
    fr = frames.copy() if new_frames.shape[0] else frames
    for n in range(new_frames.shape[0]):
        r = rows[n]
        for i in range(3):
            for j in range(3):
                fr[r, i, j] = new_frames[n, i, j]
    vec = vectors.copy()
    if moves.shape[0]:
        for n in range(moves.shape[0]):
            r = rows[n]
            m0, m1, m2 = moves[n, 0], moves[n, 1], moves[n, 2]
            same = True
            for i in range(3):
                x = offsets[r, i] + (((0.0 + fr[r, 0, i] * m0) + fr[r, 1, i] * m1) + fr[r, 2, i] * m2)
                y = offsets[r, i]
                moved[r, i] = x
                # the same bits: equal, with the same sign where zero (an int64 view of the
                # arrays compiles half a second longer); a NaN counts as changed
                same = same and x == y and (x != 0.0 or math.copysign(1.0, x) == math.copysign(1.0, y))
            if same:
                continue
            o0, o1, o2 = moved[r, 0], moved[r, 1], moved[r, 2]
            for i in range(3):
                vec[r, i] = 0.0 + ((fr[r, i, 0] * o0 + fr[r, i, 2] * o2) + fr[r, i, 1] * o1)
        return fr, vec
    for r in rows:
        o0, o1, o2 = offsets[r, 0], offsets[r, 1], offsets[r, 2]
        for i in range(3):
            vec[r, i] = 0.0 + ((fr[r, i, 0] * o0 + fr[r, i, 2] * o2) + fr[r, i, 1] * o1)
    return fr, vec


@njit(cache=True, nogil=True)
def stale_rows(stale, centre, ring, ends, every, pending):
    """Positions ``(p,) int64`` (ascending) among a level's movable CVs whose frames the level-0
    patches ``stale (P0u, P0v) bool`` reach: the CV's centre lies on one (``centre (m,) int64``,
    flat ``pu * P0v + pv``), or it is in the pole ring ``ring (m,) int64`` (-1: none) of a closed
    end ``ends[i] = (axis, end)`` with a stale patch along it, or its row (``every (m,) int64``,
    sorted) is among ``pending (q,) int64`` (frames an earlier pass left to evaluate)."""
    nu, nv = stale.shape
    along = np.zeros(ends.shape[0] + 1, np.bool_)  # the last entry: a CV on no ring
    for i in range(ends.shape[0]):
        axis, end = ends[i, 0], ends[i, 1]
        if axis == 0:
            row = nu - 1 if end else 0
            for j in range(nv):
                along[i] |= stale[row, j]
        else:
            col = nv - 1 if end else 0
            for j in range(nu):
                along[i] |= stale[j, col]
    hit = np.zeros(centre.shape[0], np.bool_)
    for i in range(centre.shape[0]):
        c = centre[i]
        hit[i] = stale[c // nv, c % nv] or along[ring[i]]
    for key in pending:  # `_find` rather than np.searchsorted, which costs seconds to compile
        hit[_find(every, key)[0]] = True
    out = np.empty(centre.shape[0], np.int64)
    n = 0
    for i in range(centre.shape[0]):
        if hit[i]:
            out[n] = i
            n += 1
    return out[:n]


@njit(cache=True, nogil=True)
def merge_points(uv, want, is_contact, level, u_patches, u_periodic, v_patches, v_periodic, trig):
    """`acra.targets.per_level_points` in one pass: the contacts of ``uv (K, 2) float64`` and
    ``want (K, 3) float64`` as they are, in order, then one row per level-``level`` patch that
    additional points (``is_contact (K,) bool`` false) fall in, patches in key order (``pu *
    v_patches + pv``, `acra.targets.patch_keys`; `unique_inverse`'s numbering): the mean of
    their wanted moves and of each open direction's parameters, each sum from 0.0 in the
    points' order then divided by the count, as ``np.bincount`` sums. A periodic direction's
    mean is an angle's (`acra.targets.patch_groups`): ``trig (2, 2, E) float64`` holds numpy's
    cosines and sines of the ``E`` additional points' angles per direction (``[col, 0]``:
    cosines, ``[col, 1]``: sines; unused for an open direction), summed here per patch into
    ``sums (g, 2, 2) float64`` for the caller's ``arctan2``. Returns the merged ``uv (n, 2)``,
    ``want (n, 3)`` (a periodic column of a patch row left for the caller) and ``sums``."""
    K = uv.shape[0]
    nc = 0
    for i in range(K):
        nc += is_contact[i]
    E = K - nc
    keys = np.empty(E, np.int64)
    e = 0
    for i in range(K):
        if not is_contact[i]:
            su = _segment(uv[i, 0], level, u_patches, u_periodic)[0]
            sv = _segment(uv[i, 1], level, v_patches, v_periodic)[0]
            keys[e] = su * v_patches + sv
            e += 1
    uniq, inv = unique_inverse(keys)
    g = uniq.shape[0]
    count = np.zeros(g, np.int64)
    plain = np.zeros((g, 2))
    moves = np.zeros((g, 3))
    sums = np.zeros((g, 2, 2))
    out_uv = np.empty((nc + g, 2))
    out_want = np.empty((nc + g, 3))
    c = e = 0
    for i in range(K):
        if is_contact[i]:
            out_uv[c, 0], out_uv[c, 1] = uv[i, 0], uv[i, 1]
            out_want[c, 0], out_want[c, 1], out_want[c, 2] = want[i, 0], want[i, 1], want[i, 2]
            c += 1
            continue
        r = inv[e]
        count[r] += 1
        for col in range(2):
            plain[r, col] += uv[i, col]
            sums[r, col, 0] += trig[col, 0, e]
            sums[r, col, 1] += trig[col, 1, e]
        for j in range(3):
            moves[r, j] += want[i, j]
        e += 1
    for r in range(g):
        n = float(count[r])
        for col in range(2):
            out_uv[nc + r, col] = plain[r, col] / n
        for j in range(3):
            out_want[nc + r, j] = moves[r, j] / n
    return out_uv, out_want, sums
