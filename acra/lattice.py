"""Compiled sorted sets of lattice points, for the adaptive display mesh (`acra.tessellate`).

The adaptive topology's vertices are points ``(i, j)`` of an integer lattice, ``0 <= i <= ni``,
``0 <= j < w``, kept as sorted keys ``i * w + j``. In array form they are ``np.unique`` of every
cell corner's key with its inverse: a sort of four keys a cell over the whole set. Here the keys
are bucketed by ``i`` (a counting sort: each column's few keys sorted alone; a mesh's cell
corners, already in order along each line, by one merge a line, `_corner_keys`), and each
point's position among the keys comes out of the same pass, so the mesh finds every corner's
vertex (and, as corners bound each cell side, the vertices between them) without a search. The keys, the
positions and the column starts are the same as numpy's (`tests/test_tessellate.py` holds them to
``np.unique`` and ``np.searchsorted``).
A mesh's vertices at given parameters are found by a binary search over their sorted ``(u,
v)`` (`half_patch_points`: `pipeline.shape`'s coarse samples read from a display).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["unique_keys", "quadtree_leaves", "adaptive_mesh", "fan_triangles", "half_patch_points"]


@njit(inline="always")
def _key_order(i, j, ni, w):
    """The points ``(i[p], j[p])`` ordered by key ``i * w + j`` (stable), ``(n,) int32``, by two
    stable counting sorts (by j, then by i), and each column's first position in that order
    ``(ni + 2,) int64``."""
    n = i.shape[0]
    if n >= 2**31:
        raise ValueError("too many points for int32 orders")
    count = np.zeros(w + 1, np.int64)
    for p in range(n):
        count[j[p] + 1] += 1
    for x in range(w):
        count[x + 1] += count[x]
    # the orders as int32 (a mesh's points number far below 2**31): half the new memory, whose
    # page faults cost more than the sort
    by_j = np.empty(n, np.int32)
    for p in range(n):
        by_j[count[j[p]]] = p
        count[j[p]] += 1
    first = np.zeros(ni + 2, np.int64)
    for p in range(n):
        first[i[p] + 1] += 1
    for c in range(ni + 1):
        first[c + 1] += first[c]
    fill = first.copy()
    order = np.empty(n, np.int32)
    for q in range(n):
        p = by_j[q]
        order[fill[i[p]]] = p
        fill[i[p]] += 1
    return order, first


@njit(cache=True, nogil=True)
def unique_keys(i, j, ni, w):
    """The sorted distinct keys ``i * w + j`` of the points ``(i[p], j[p])`` (``0 <= i <= ni``,
    ``0 <= j < w``), ``(m,) int64``; where each column ``i`` starts in them, ``(ni + 2,) int64``
    (entry ``ni + 1`` is ``m``); and the position of each point's key in them, ``(n,) int64``
    (``np.unique``'s inverse)."""
    n = i.shape[0]
    order, first = _key_order(i, j, ni, w)
    out = np.empty(n, np.int64)
    where = np.empty(n, np.int64)
    m = 0
    last = -1
    c = 0
    for q in range(n):
        p = order[q]
        x = i[p] * w + j[p]
        if x != last:
            while c <= i[p]:  # the columns up to this key's start here
                first[c] = m
                c += 1
            out[m] = x
            m += 1
            last = x
        where[p] = m - 1
    while c <= ni + 1:
        first[c] = m
        c += 1
    return out[:m].copy(), first, where


@njit(cache=True, nogil=True)
def quadtree_leaves(p0u, p0v, keys, starts):
    """The quadtree's leaves over the ``p0u`` by ``p0v`` level-0 patches (`acra.tessellate._leaves`,
    in its order): per level ``k`` from 0 to ``top``, the level-``k`` patches that hold no present
    patch of a finer level while their parent holds one, in the order the walk down opens them.

    ``keys (s,) int64``: per level ``j`` from 1 to ``top``, the keys ``pu * (p0v << j) + pv`` of
    the patches where level ``j`` is present (any order, repeats allowed), level ``j``'s at
    ``starts[j - 1]`` to ``starts[j]`` (``starts (top + 1,) int64``, ``starts[0] = 0``).

    Returns each leaf's patch ``pu, pv (l,) int64`` in units of its own level and that level ``(l,)
    int64``. Per level, the sorted distinct keys of the patches holding a finer present one (the
    parents of the level below's present and holding ones) are built from the finest up, then
    the walk down from the level-0 patches looks each open patch up in them: the cost follows the
    refined area, as the array form's, without its per-level temporaries."""
    top = starts.shape[0] - 1
    total = starts[top]
    hold = np.empty(total * max(top, 1) + 1, np.int64)  # every level's holding keys, finest first
    h_lo, h_hi = np.zeros(top + 1, np.int64), np.zeros(top + 1, np.int64)
    pos = 0
    below_lo, below_hi = 0, 0
    for k in range(top - 1, -1, -1):
        wide, narrow = p0v << (k + 1), p0v << k
        tmp = np.empty(starts[k + 1] - starts[k] + below_hi - below_lo, np.int64)
        t = 0
        for a in range(starts[k], starts[k + 1]):  # level k + 1's present patches
            x = keys[a]
            tmp[t] = ((x // wide) >> 1) * narrow + ((x % wide) >> 1)
            t += 1
        for a in range(below_lo, below_hi):  # and those holding a finer one
            x = hold[a]
            tmp[t] = ((x // wide) >> 1) * narrow + ((x % wide) >> 1)
            t += 1
        # the kernels' one sort (`adaptive_mesh`'s: int64 keys), so no other is compiled
        by = np.argsort(tmp, kind="mergesort")
        lo = pos
        for a in range(t):
            x = tmp[by[a]]
            if pos == lo or x != hold[pos - 1]:
                hold[pos] = x
                pos += 1
        h_lo[k], h_hi[k] = lo, pos
        below_lo, below_hi = lo, pos
    # every open patch is a leaf or holds one: the level-0 ones and 4 children per holding one
    cap = p0u * p0v + 4 * pos
    lu, lv, lk = np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap, np.int64)
    ou, ov = np.empty(p0u * p0v, np.int64), np.empty(p0u * p0v, np.int64)
    n = 0
    for a in range(p0u):
        for b in range(p0v):
            ou[n], ov[n] = a, b
            n += 1
    nl = 0
    for k in range(top + 1):
        lo, hi = h_lo[k], h_hi[k]
        width = p0v << k
        nu_, nv_ = np.empty(4 * (hi - lo), np.int64), np.empty(4 * (hi - lo), np.int64)
        m = 0
        for a in range(n):
            busy = False
            if hi > lo:
                x = ou[a] * width + ov[a]
                i, j = lo, hi  # the first holding key not below x, by bisection
                while i < j:
                    mid = (i + j) >> 1
                    if hold[mid] < x:
                        i = mid + 1
                    else:
                        j = mid
                busy = i < hi and hold[i] == x
            if busy:
                for du in range(2):
                    for dv in range(2):
                        nu_[m], nv_[m] = 2 * ou[a] + du, 2 * ov[a] + dv
                        m += 1
            else:
                lu[nl], lv[nl], lk[nl] = ou[a], ov[a], k
                nl += 1
        ou, ov, n = nu_, nv_, m
    return lu[:nl].copy(), lv[:nl].copy(), lk[:nl].copy()


@njit(inline="always")
def _corner_keys(su, sv, sh, starts, stops, ends, nu, nv, wrap_u, wrap_v, w):
    """`unique_keys` of the four corners of every cell ``(su, sv, sh) (nc,) int64`` (sorted by
    their lower corners' keys; corner ``s`` of cell ``c`` is the point ``4 c + s``,
    counter-clockwise from the lower one: 0 ``(u, v)``, 1 ``(u + h, v)``, 2 ``(u + h, v + h)``, 3
    ``(u, v + h)``, an upper corner on a periodic seam wrapped onto its first line): the sorted
    distinct keys ``(m,) int64``, each column's start ``(nu + 2,) int64`` and each corner's
    position in the keys ``(4 nc,) int32``.

    The cells tile the domain, so on each lattice line ``u = i`` the cells starting there
    (corners 0 and 3) have disjoint v ranges, and so have the cells ending there (corners 1 and
    2): each side's corners, cell by cell in v order, are already sorted along the line. The
    cells starting on line ``i`` are ``starts[i]`` to ``starts[i + 1]`` in the cells' order; those
    ending on it, in v order, are ``ends[stops[i]:stops[i + 1]]`` (``starts, stops (nu + 2,)
    int64``, ``ends (nc,) int64``: `adaptive_mesh` writes them as it orders the cells). One merge
    of the two sides per line gives its keys in order, each corner's position as it passes, with
    no sort of the corners. A corner on the periodic v seam (``v + h = nv``) is the line's vertex
    at ``v = 0``, its first."""
    nc = su.shape[0]
    n = 4 * nc
    if n >= 2**31:
        raise ValueError("too many points for int32 orders")
    out = np.empty(n, np.int64)
    at = np.empty(n, np.int32)
    first = np.empty(nu + 2, np.int64)
    m = 0
    for i in range(nu + 1):
        first[i] = m
        b, b_end = starts[i], starts[i + 1]
        a, a_end = stops[i], stops[i + 1]
        if b == b_end and a == a_end:
            continue
        # each side's last corner is its highest: a line reaches the periodic v seam where one does
        seam = wrap_v and ((b < b_end and sv[b_end - 1] + sh[b_end - 1] == nv)
                           or (a < a_end and sv[ends[a_end - 1]] + sh[ends[a_end - 1]] == nv))
        line = m
        last = -1
        if seam:
            out[m] = i * w
            m += 1
            last = 0
        upper_b, upper_a = 0, 0  # whether the current cell's next corner is its upper one
        while b < b_end or a < a_end:
            jb = sv[b] + sh[b] * upper_b if b < b_end else w
            ca = ends[a] if a < a_end else 0
            ja = sv[ca] + sh[ca] * upper_a if a < a_end else w
            if jb <= ja:
                j, p = jb, 4 * b + 3 * upper_b
                b += upper_b
                upper_b ^= 1
            else:
                j, p = ja, 4 * ca + 1 + upper_a
                a += upper_a
                upper_a ^= 1
            if seam and j == nv:
                at[p] = line
                continue
            if j != last:
                out[m] = i * w + j
                m += 1
                last = j
            at[p] = m - 1
    first[nu + 1] = m
    return out[:m].copy(), first, at


@njit(inline="always")
def _upper(x, n, wrap):
    """Lattice line ``x`` (at most ``n``) of a cell's upper side, the seam's ``n`` as its ``0``
    where the direction wraps."""
    return 0 if wrap and x == n else x


@njit(inline="always")
def _side(c, s, su, sv, sh, at, u_to_v, first, first_v, nu, nv, wrap_u, wrap_v):
    """The rows ``lo, hi`` of the vertices strictly inside side ``s`` of cell ``c`` (0: its lower
    side along u, 1: its upper side along v, 2: its upper side along u, 3: its lower side along
    v), in `adaptive_mesh`'s v-major rows for a side along u and u-major along v; a side ending
    on a periodic seam runs to its line's end (``at (4 nc,) int32``: corner ``s`` of cell ``c``'s
    row at ``4 c + s``, `_corner_keys`)."""
    u1, v1 = su[c] + sh[c], sv[c] + sh[c]
    seam_u = wrap_u and u1 == nu
    seam_v = wrap_v and v1 == nv
    if s == 0:
        return u_to_v[at[4 * c]] + 1, first_v[sv[c] + 1] if seam_u else u_to_v[at[4 * c + 1]]
    if s == 1:
        return at[4 * c + 1] + 1, first[(0 if seam_u else u1) + 1] if seam_v else at[4 * c + 2]
    if s == 2:
        return u_to_v[at[4 * c + 3]] + 1, first_v[(0 if seam_v else v1) + 1] if seam_u else u_to_v[at[4 * c + 2]]
    return at[4 * c] + 1, first[su[c] + 1] if seam_v else at[4 * c + 3]


@njit(cache=True, nogil=True)
def adaptive_mesh(pu, pv, ph, samples, nu, nv, wrap_u, wrap_v):
    """The adaptive display mesh of the quadtree leaves ``(pu, pv)`` (`acra.tessellate._leaves`)
    in one pass: each leaf's patch ``(l,) int64`` in units of its own level and its cells' step
    ``ph`` ``(l,) int64`` on a lattice of ``nu`` by ``nv`` steps (``wrap_u``, ``wrap_v``: a
    periodic seam's last line is its first), ``samples`` cells a leaf's edge.

    Returns the vertices' lattice coordinates ``(n,) int64`` each, sorted by ``(u, v)``; the
    faces' vertex counts ``(q + t,) int64`` and indices ``(4 q + 3 t,) int64`` (the quads of the
    unsplit cells, then each split cell's fan of triangles about a vertex at its centre, cells in
    ``(u, v)`` order); and the vertices' rows by ``(v, u)`` ``(n,) int64`` (numpy's stable
    ``argsort`` of their v: the order a display is evaluated in, `acra.tessellate.grid_samples`). A cell is split where a finer neighbour puts a vertex strictly inside one
    of its sides: its ring walks the sides counter-clockwise, each corner then the vertices inside
    the side, so its triangles are those of the array form, in its order."""
    w = nv + 1
    nl = pu.shape[0]
    nc = nl * samples * samples
    # the cells in (u, v) order, written there leaf by leaf: the leaves by the v of their lower
    # corner (a stable counting sort of the leaves, not of their cells), then each leaf's rows of
    # cells appended to their lattice lines. The leaves meeting a line cover disjoint v ranges,
    # so each line's cells come in v order; the lower corners are distinct, so this is the one
    # (u, v) order of the cells
    count = np.zeros(w + 1, np.int64)
    for leaf in range(nl):
        count[pv[leaf] * samples * ph[leaf] + 1] += 1
    for x in range(w):
        count[x + 1] += count[x]
    leaf_by_v = np.empty(nl, np.int64)
    for leaf in range(nl):
        x = pv[leaf] * samples * ph[leaf]
        leaf_by_v[count[x]] = leaf
        count[x] += 1
    fill = np.zeros(nu + 2, np.int64)  # per lattice line u, where its cells start
    for leaf in range(nl):
        for a in range(samples):
            fill[(pu[leaf] * samples + a) * ph[leaf] + 1] += samples
    for x in range(nu + 1):
        fill[x + 1] += fill[x]
    starts = fill.copy()
    # and per lattice line, the cells whose upper side lies on it (`_corner_keys`' ``ends``), in
    # v order by the same walk
    stops = np.zeros(nu + 2, np.int64)
    for leaf in range(nl):
        for a in range(samples):
            stops[_upper((pu[leaf] * samples + a + 1) * ph[leaf], nu, wrap_u) + 1] += samples
    for x in range(nu + 1):
        stops[x + 1] += stops[x]
    fill_up = stops.copy()
    su, sv, sh = np.empty(nc, np.int64), np.empty(nc, np.int64), np.empty(nc, np.int64)
    ends = np.empty(nc, np.int64)
    for q in range(nl):
        leaf = leaf_by_v[q]
        h = ph[leaf]
        for a in range(samples):
            line = (pu[leaf] * samples + a) * h
            c = fill[line]
            r = _upper(line + h, nu, wrap_u)
            e = fill_up[r]
            for b in range(samples):
                su[c + b], sv[c + b], sh[c + b] = line, (pv[leaf] * samples + b) * h, h
                ends[e + b] = c + b
            fill[line] = c + samples
            fill_up[r] = e + samples
    # the corners' vertices (corner s of cell c at 4 c + s, `_corner_keys`)
    lattice, first, at = _corner_keys(su, sv, sh, starts, stops, ends, nu, nv, wrap_u, wrap_v, w)
    # the same vertices v-major: a stable counting sort of the u-major ones by v
    # (a key's v is its offset from its column's start key: no division)
    m = lattice.shape[0]
    first_v = np.zeros(nv + 2, np.int64)
    for c in range(nu + 1):
        for a in range(first[c], first[c + 1]):
            first_v[lattice[a] - c * w + 1] += 1
    for x in range(nv + 1):
        first_v[x + 1] += first_v[x]
    fill = first_v.copy()
    v_to_u = np.empty(m, np.int64)
    u_to_v = np.empty(m, np.int64)
    for c in range(nu + 1):
        for a in range(first[c], first[c + 1]):
            x = lattice[a] - c * w
            v_to_u[fill[x]] = a
            u_to_v[a] = fill[x]
            fill[x] += 1
    # each side's vertices strictly inside it, rows lo..hi-1 along its line (`_side`), taken
    # where they are used rather than kept for every cell: the scratch arrays of a large mesh
    # are new memory, whose page faults cost more than the few operations again
    split = np.zeros(nc, np.bool_)
    ring_len = 0
    n_split = 0
    for c in range(nc):
        # `_side` of the four sides, written out: this loop visits every cell
        seam_u = wrap_u and su[c] + sh[c] == nu
        seam_v = wrap_v and sv[c] + sh[c] == nv
        a0, a1, a2, a3 = at[4 * c], at[4 * c + 1], at[4 * c + 2], at[4 * c + 3]
        n0 = (first_v[sv[c] + 1] if seam_u else u_to_v[a1]) - u_to_v[a0] - 1
        n1 = (first[(0 if seam_u else su[c] + sh[c]) + 1] if seam_v else a2) - a1 - 1
        n2 = (first_v[(0 if seam_v else sv[c] + sh[c]) + 1] if seam_u else u_to_v[a2]) - u_to_v[a3] - 1
        n3 = (first[su[c] + 1] if seam_v else a3) - a0 - 1
        if n0 > 0 or n1 > 0 or n2 > 0 or n3 > 0:
            split[c] = True
            n_split += 1
            ring_len += 4 + max(n0, 0) + max(n1, 0) + max(n2, 0) + max(n3, 0)
    # the split cells' centres (inside their cells, so no corner's) sorted and merged with the
    # corners: a corner's row moves up by the centres before it, a centre's is its rank plus the
    # corners before it
    centre = np.empty(n_split, np.int64)
    k = 0
    for c in range(nc):
        if split[c]:
            centre[k] = (su[c] + sh[c] // 2) * w + sv[c] + sh[c] // 2
            k += 1
    by = np.argsort(centre, kind="mergesort")  # the kernels' one sort (distinct keys: any order is this one)
    row = np.empty(m, np.int64)
    centre_row = np.empty(n_split, np.int64)
    a = 0
    for b in range(n_split):
        x = centre[by[b]]
        while a < m and lattice[a] < x:
            row[a] = a + b
            a += 1
        centre_row[by[b]] = a + b
    while a < m:
        row[a] = a + n_split
        a += 1
    quads = nc - n_split
    indices = np.empty(4 * quads + 3 * ring_len, np.int64)
    q = 0
    for c in range(nc):
        if not split[c]:
            for s in range(4):
                indices[q] = row[at[4 * c + s]]
                q += 1
    ring = np.empty(ring_len, np.int64)
    k = 0
    for c in range(nc):
        if not split[c]:
            continue
        n = 0
        for s in range(4):
            ring[n] = at[4 * c + s]
            n += 1
            lo, hi = _side(c, s, su, sv, sh, at, u_to_v, first, first_v, nu, nv, wrap_u, wrap_v)
            if s == 0:
                for r in range(lo, hi):
                    ring[n] = v_to_u[r]
                    n += 1
            elif s == 1:
                for r in range(lo, hi):
                    ring[n] = r
                    n += 1
            elif s == 2:
                for r in range(hi - 1, lo - 1, -1):
                    ring[n] = v_to_u[r]
                    n += 1
            else:
                for r in range(hi - 1, lo - 1, -1):
                    ring[n] = r
                    n += 1
        for t in range(n):
            indices[q] = centre_row[k]
            indices[q + 1] = row[ring[t]]
            indices[q + 2] = row[ring[(t + 1) % n]]
            q += 3
        k += 1
    counts = np.full(quads + (q - 4 * quads) // 3, 3, np.int64)
    counts[:quads] = 4
    # each vertex's lattice point in its row: a corner's column from the column starts (no
    # division), a centre's from its key
    ku, kv = np.empty(m + n_split, np.int64), np.empty(m + n_split, np.int64)
    for c in range(nu + 1):
        for a in range(first[c], first[c + 1]):
            ku[row[a]], kv[row[a]] = c, lattice[a] - c * w
    for b in range(n_split):
        x = centre[b] // w
        ku[centre_row[b]], kv[centre_row[b]] = x, centre[b] - x * w
    # the rows by v, a stable counting sort of the u-major rows (so by u within a v)
    start = np.zeros(nv + 2, np.int64)
    for a in range(m + n_split):
        start[kv[a] + 1] += 1
    for x in range(nv + 1):
        start[x + 1] += start[x]
    by_v = np.empty(m + n_split, np.int64)
    for a in range(m + n_split):
        by_v[start[kv[a]]] = a
        start[kv[a]] += 1
    return ku, kv, counts, indices, by_v


@njit(cache=True, nogil=True)
def fan_triangles(counts, indices):
    """Every face of a mesh as triangles, a fan from its first vertex, face by face: the faces'
    vertex counts ``(f,) int64`` and indices ``(sum counts,) int64`` (USD's) give ``(t, 3)
    int64``, a face of ``n`` vertices ``n - 2`` triangles (a quad ``a b c d``: ``a b c``,
    ``a c d``). One pass, where numpy's takes a temporary per step."""
    t = 0
    for f in range(counts.shape[0]):
        t += max(counts[f] - 2, 0)
    out = np.empty((t, 3), np.int64)
    k = 0
    start = 0
    for f in range(counts.shape[0]):
        a = indices[start]
        for e in range(1, counts[f] - 1):
            out[k, 0], out[k, 1], out[k, 2] = a, indices[start + e], indices[start + e + 1]
            k += 1
        start += counts[f]
    return out


@njit(cache=True, nogil=True)
def half_patch_points(u, v, points, patches, p0v, wrap_u, wrap_v, out):
    """Copy a mesh's vertex points at level-0 patches' half-patch samples, if it has them all.

    ``u, v (n,) float64``: the vertices' parameters (level-0 units), sorted by ``(u, v)``
    (`acra.tessellate.MeshTopology`'s), ``points (n, 3)`` theirs. Each patch marked in
    ``patches (P0u P0v,) bool`` (row-major over ``P0v`` columns) has 9 samples ``(pu + i / 2,
    pv + j / 2)``, ``i`` slowest, whose points go to rows ``9 p .. 9 p + 8`` of ``out (9 P0u
    P0v, 3)`` (`pipeline.shape`'s `coarse_points` order; the other rows are left as they are);
    a wrapped direction's end is looked up at 0, the seam's one vertex. Each sample is found by
    a binary search over ``(u, v)``. Returns False (``out`` partly written) at the first sample
    with no vertex."""
    n = u.shape[0]
    p0u = patches.shape[0] // p0v
    for p in range(patches.shape[0]):
        if not patches[p]:
            continue
        pu, pv = p // p0v, p % p0v
        r = 9 * p
        for i in range(3):
            a2 = 2 * pu + i
            if wrap_u and a2 == 2 * p0u:
                a2 = 0
            a = a2 / 2.0
            for j in range(3):
                b2 = 2 * pv + j
                if wrap_v and b2 == 2 * p0v:
                    b2 = 0
                b = b2 / 2.0
                lo, hi = 0, n
                while lo < hi:  # the first vertex not before (a, b)
                    mid = (lo + hi) >> 1
                    if u[mid] < a or (u[mid] == a and v[mid] < b):
                        lo = mid + 1
                    else:
                        hi = mid
                if lo == n or u[lo] != a or v[lo] != b:
                    return False
                out[r, 0], out[r, 1], out[r, 2] = points[lo, 0], points[lo, 1], points[lo, 2]
                r += 1
    return True
