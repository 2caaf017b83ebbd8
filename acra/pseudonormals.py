"""A part of a closed triangle mesh and its pseudo-normals, compiled (`pipeline.clearance.solid`
with ``part``).

The residual where the user looks builds, every round, the part of the other object's display
near the inner object's triangles (welded, narrow and repeated faces dropped, its face, edge and
angle-weighted vertex pseudo-normals): thousands of faces, some thirty numpy calls each paying its
set-up. `part_mesh` does the same arithmetic in one pass per step, element by element in the
order numpy's calls take (``np.cross`` as ``a1 b2 - a2 b1``; a norm over 3 components as
``(x0² + x1²) + x2²``; ``np.einsum`` of 3 products as ``(p0 + p2) + p1``; ``np.bincount``
summing in input order; stable sorts where rows tie), so it gives the same bits;
``tests/test_clearance.py`` holds it to the array form. The corner angles' ``arctan2`` stays
numpy's (a compiled ``atan2`` rounds differently), between `part_mesh` and `vertex_normals`.

Arrays are float64 unless stated.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["weld", "part_mesh", "welded_part", "vertex_normals", "signs", "links", "flood", "representatives"]


@njit(cache=True, nogil=True)
def _unit_rows(x):
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        n = np.sqrt((x[i, 0] * x[i, 0] + x[i, 1] * x[i, 1]) + x[i, 2] * x[i, 2])
        d = n if n > 0 else 1.0
        out[i, 0], out[i, 1], out[i, 2] = x[i, 0] / d, x[i, 1] / d, x[i, 2] / d
    return out


@njit(cache=True, nogil=True)
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True, nogil=True)
def _root(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True, nogil=True)
def _used(v, f, rows):
    """The vertices of ``v (n, 3)`` that the faces ``f[rows]`` use, renumbered in the order of
    their rows: ``(new (n,) int64`` (-1 where unused), ``vertices (k, 3))``."""
    new = np.full(v.shape[0], -1, np.int64)
    for i in range(rows.shape[0]):
        for k in range(3):
            new[f[rows[i], k]] = 0
    n = 0
    for j in range(v.shape[0]):
        if new[j] == 0:
            new[j] = n
            n += 1
    out = np.empty((n, 3))
    for j in range(v.shape[0]):
        if new[j] >= 0:
            # element by element: a row assigned from an array would compile numba's shape-
            # mismatch message (its string formatting) into the first run
            for k in range(3):
                out[new[j], k] = v[j, k]
    return new, out


@njit(cache=True, nogil=True)
def _popcount(x):
    """The bits set in the ``uint64`` ``x`` (summed in pairs, nibbles, then bytes)."""
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return np.int64((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@njit(cache=True, nogil=True)
def _used_bits(v, f):
    """`_used` of every face of ``f (F, 3) int64`` as each corner's place among the used
    vertices ``(F, 3) int64`` (`_used`'s ``new[f]``) and those vertices ``(k, 3)``, through one
    bit per vertex of ``v (n, 3)``: a vertex's place is the count of used vertices below it, the
    counts of the words before its word plus the bits below it in its word. A part of a large
    display uses a few hundred of its tens of thousands of points, and `_used`'s three passes
    over all of them cost more than the part's weld."""
    words = (v.shape[0] + 63) // 64
    bits = np.zeros(words, np.uint64)
    for i in range(f.shape[0]):
        for k in range(3):
            j = f[i, k]
            bits[j >> 6] |= np.uint64(1) << np.uint64(j & 63)
    before = np.empty(words, np.int64)  # the used vertices in the words before
    total = 0
    for w in range(words):
        before[w] = total
        total += _popcount(bits[w])
    out = np.empty((total, 3))
    r = 0
    for w in range(words):  # each used vertex in increasing row, its values element by element (`_used`)
        x = bits[w]
        while x:
            low = x & (~x + np.uint64(1))
            j = 64 * w + _popcount(low - np.uint64(1))
            for k in range(3):
                out[r, k] = v[j, k]
            r += 1
            x ^= low
    place = np.empty((f.shape[0], 3), np.int64)
    for i in range(f.shape[0]):
        for k in range(3):
            j = f[i, k]
            place[i, k] = before[j >> 6] + _popcount(bits[j >> 6] & ((np.uint64(1) << np.uint64(j & 63)) - np.uint64(1)))
    return place, out


SPARSE = 16  # `weld` numbers the used vertices by bits where the points outnumber the faces this many times


@njit(cache=True, nogil=True)
def _join(parent, i, j, dx, dy, dz, below):
    """Joins ``i`` and ``j``, whose difference is ``(dx, dy, dz)`` and squared distance at most
    `weld`'s ``above``, if it is at most ``below``; false if not (undecided). `_pairs_by_cells`
    tests ``above`` inline: most pairs it finds are apart, and a call per pair costs more than
    its test."""
    if (dx * dx + dy * dy) + dz * dz > below:
        return False
    ri, rj = _root(parent, i), _root(parent, j)
    if ri != rj:
        parent[max(ri, rj)] = min(ri, rj)
    return True


@njit(cache=True, nogil=True)
def _pairs_by_cells(vu, parent, below, above, reach):
    """`weld`'s pairs: every pair of ``vu (g, 3)`` whose x differ by at most ``reach`` goes to
    `_join` (the distance test inline; the sign of a difference does not change its square), so
    the groups are the connected components of the pairs within ``radius``, whatever the order.
    The points are chained by their cell ``floor(x / (1.5 reach))`` along x in a hash table, so
    such a pair lies in one cell or two neighbouring ones, each chain in decreasing row: a point
    walks its own cell's chain down to its row and the next cell's (``+1``) whole, so each pair
    is tested once, from its lower row in one cell or from the lower cell, and a point looks up
    one cell besides its own, whose slot it keeps from its insertion. No sort (a sort of the
    points by x cost a display's part more than the rest of the weld). A point whose three
    differences from the last point chained in its cell are 0 (the same values: a pole row's
    copies, which come in consecutive rows) joins that point and stays out of the chains: its
    differences from any third point are that point's, but for a zero's sign, so each of its
    pairs is decided as that point's is, and a pole's copies are not tested pair by pair (the
    chain's head alone is compared: a ring of points sharing their x costs no more). Returns 1 if joined, 0 if a pair was undecided, -1 if a
    coordinate is too large for its cell to be an exact integer (``|x| >= 2^50`` cells)."""
    g = vu.shape[0]
    cell = 1.5 * reach
    q = np.empty(g, np.int64)
    for i in range(g):
        x = vu[i, 0] / cell
        if not abs(x) < 2.0 ** 50:  # also NaN
            return -1
        q[i] = np.int64(np.floor(x))
    size, bits = 16, 4
    while size < 2 * g:
        size, bits = 2 * size, bits + 1
    shift, mask = np.uint64(64 - bits), size - 1
    key = np.empty(size, np.int64)
    head = np.full(size, -1, np.int64)  # each cell's points, chained through ``after``
    after = np.full(g, -1, np.int64)
    at = np.full(g, -1, np.int64)  # each chained point's slot; -1 for a copy
    for i in range(g):
        slot = np.int64((np.uint64(q[i]) * np.uint64(0x9E3779B97F4A7C15)) >> shift)
        while head[slot] >= 0 and key[slot] != q[i]:
            slot = (slot + 1) & mask
        key[slot] = q[i]
        j = head[slot]  # differences of 0 (not a test of equality: inf - inf is not 0)
        if j >= 0 and vu[i, 0] - vu[j, 0] == 0.0 and vu[i, 1] - vu[j, 1] == 0.0 and vu[i, 2] - vu[j, 2] == 0.0:
            # distance 0, within ``below`` (``radius > 0``)
            ri, rj = _root(parent, i), _root(parent, j)
            if ri != rj:
                parent[max(ri, rj)] = min(ri, rj)
            continue
        at[i] = slot
        after[i] = head[slot]
        head[slot] = i
    for i in range(g):
        if at[i] < 0:
            continue
        j = head[at[i]]
        while j > i:  # the own cell's points of higher rows
            dx = vu[j, 0] - vu[i, 0]
            if abs(dx) <= reach:
                dy, dz = vu[j, 1] - vu[i, 1], vu[j, 2] - vu[i, 2]
                if (dx * dx + dy * dy) + dz * dz <= above and not _join(parent, i, j, dx, dy, dz, below):
                    return 0
            j = after[j]
        c = q[i] + 1
        slot = np.int64((np.uint64(c) * np.uint64(0x9E3779B97F4A7C15)) >> shift)
        while head[slot] >= 0 and key[slot] != c:
            slot = (slot + 1) & mask
        j = head[slot]
        while j >= 0:  # the next cell's points, every row
            dx = vu[j, 0] - vu[i, 0]
            if abs(dx) <= reach:
                dy, dz = vu[j, 1] - vu[i, 1], vu[j, 2] - vu[i, 2]
                if (dx * dx + dy * dy) + dz * dz <= above and not _join(parent, i, j, dx, dy, dz, below):
                    return 0
            j = after[j]
    return 1


@njit(cache=True, nogil=True)
def weld(v, f, radius):
    """The vertices ``v (n, 3)`` that faces ``f (F, 3) int64`` use, welded: chained by distances
    within ``radius``, each group one vertex, its lowest row's, groups in the order of their
    lowest rows (`pipeline.clearance._weld`'s connected components over the used vertices).
    Where the points outnumber the faces `SPARSE` times (a part of a large display) the used
    vertices are numbered by a bit per point (`_used_bits`), else by a pass over them (`_used`).

    Returns ``(code, vertices (g, 3), faces (F, 3) int64)``; ``code`` 1 (and nothing else) if a
    pair's distance lies within 1e-9 of ``radius`` relative, where another computation of the
    distance might decide otherwise, or a coordinate lies beyond ``2^50`` times the radius
    (`_pairs_by_cells`; the caller then welds with its kd-tree)."""
    if v.shape[0] > SPARSE * f.shape[0]:  # a part of a large display: no pass over all its points
        place, vu = _used_bits(v, f)
    else:
        rank, vu = _used(v, f, np.arange(f.shape[0]))
        place = np.empty((f.shape[0], 3), np.int64)
        for i in range(f.shape[0]):
            for k in range(3):
                place[i, k] = rank[f[i, k]]
    g = vu.shape[0]
    parent = np.arange(g)
    if radius > 0:
        r2 = radius * radius
        below, above, reach = r2 * (1.0 - 1e-9), r2 * (1.0 + 1e-9), radius * (1.0 + 1e-6)
        if _pairs_by_cells(vu, parent, below, above, reach) <= 0:
            return 1, np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    label = np.full(g, -1, np.int64)
    group = np.full(g, -1, np.int64)
    count = 0
    first = np.empty(g, np.int64)
    for i in range(g):
        r = _root(parent, i)
        if group[r] < 0:
            group[r] = count
            first[count] = i
            count += 1
        label[i] = group[r]
    vw = np.empty((count, 3))
    for k in range(count):
        for q in range(3):  # element by element, as in `_used`
            vw[k, q] = vu[first[k], q]
    fw = np.empty((f.shape[0], 3), np.int64)
    for i in range(f.shape[0]):
        for k in range(3):
            fw[i, k] = label[place[i, k]]
    return 0, vw, fw


@njit(cache=True, nogil=True)
def _buckets(key, n):
    """Rows of ``key (r,) int64`` (values in ``0 .. n-1``) grouped by value, each group in row
    order: ``(start (n + 1,) int64, member (r,) int64)``, value ``x``'s rows ``member[start[x] :
    start[x + 1]]``."""
    start = np.zeros(n + 1, np.int64)
    for i in range(key.shape[0]):
        start[key[i] + 1] += 1
    for x in range(n):
        start[x + 1] += start[x]
    fill = start[:-1].copy()
    member = np.empty(key.shape[0], np.int64)
    for i in range(key.shape[0]):
        member[fill[key[i]]] = i
        fill[key[i]] += 1
    return start, member


_SMALL = 32  # a bucket of more faces or edges than this (a pole's fan) is matched by sorting


@njit(cache=True, nogil=True)
def part_mesh(v, f, radius, flip):
    """The part's mesh from welded ``v (g, 3)`` and relabelled ``f (F, 3) int64``: drops faces no
    wider than ``radius`` (twice the area over the longest edge) and repeated faces (the first
    kept), keeps the vertices used, checks each edge has at most two faces traversing it
    oppositely, and reverses the winding if ``flip``.

    Returns ``(code, v (n, 3), f (m, 3) int64, normals (m, 3), edge_normals (m, 3, 3), sin
    (m, 3), cos (m, 3))``: ``code`` 0, or 1 (no face left), 2 (an edge of more than two faces), 3
    (an edge traversed the same way twice), for the array form to raise its error; ``sin`` and
    ``cos`` are each corner's ``|e1 x e2|`` and ``e1 . e2``, for its angle."""
    g = v.shape[0]
    nf = f.shape[0]
    keep = np.zeros(nf, np.bool_)
    for r in range(nf):
        a, b, c = f[r, 0], f[r, 1], f[r, 2]
        e10, e11, e12 = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
        e20, e21, e22 = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
        x0, x1, x2 = _cross(e10, e11, e12, e20, e21, e22)
        area2 = np.sqrt((x0 * x0 + x1 * x1) + x2 * x2)
        longest = -np.inf
        for k in range(3):
            p, q = f[r, k], f[r, (k + 1) % 3]
            d0, d1, d2 = v[q, 0] - v[p, 0], v[q, 1] - v[p, 1], v[q, 2] - v[p, 2]
            s = (d0 ** 2 + d1 ** 2) + d2 ** 2
            if s > longest:
                longest = s
        keep[r] = area2 > radius * np.sqrt(longest)
    rows = np.nonzero(keep)[0]
    m = rows.shape[0]
    empty = (np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)),
             np.zeros((0, 3)))
    if m == 0:
        return (1,) + empty
    # repeated faces: the first of each sorted corner triple, in the given order (faces bucketed
    # by their lowest corner, in row order, and compared within the bucket)
    low = np.empty(m, np.int64)
    rest = np.empty((m, 2), np.int64)
    for i in range(m):
        a, b, c = f[rows[i], 0], f[rows[i], 1], f[rows[i], 2]
        lo, hi = min(a, min(b, c)), max(a, max(b, c))
        low[i], rest[i, 0], rest[i, 1] = lo, a + b + c - lo - hi, hi
    start, member = _buckets(low, g)
    first = np.ones(m, np.bool_)
    for x in range(g):
        if start[x + 1] - start[x] > _SMALL:  # a pole's fan: sorted, not pair by pair
            seg = member[start[x]:start[x + 1]]
            key = rest[seg, 0] * g + rest[seg, 1]
            order = np.argsort(key, kind="mergesort")  # equal triples in row order
            for r in range(1, order.shape[0]):
                if key[order[r]] == key[order[r - 1]]:
                    first[seg[order[r]]] = False
            continue
        for p in range(start[x], start[x + 1]):
            i = member[p]
            for q in range(start[x], p):
                j = member[q]
                if rest[j, 0] == rest[i, 0] and rest[j, 1] == rest[i, 1]:
                    first[i] = False
                    break
    rows = rows[np.nonzero(first)[0]]
    m = rows.shape[0]
    # the vertices used, renumbered in order
    new, vo = _used(v, f, rows)
    n = vo.shape[0]
    fo = np.empty((m, 3), np.int64)
    for i in range(m):
        for k in range(3):
            fo[i, 2 - k if flip else k] = new[f[rows[i], k]]
    # every undirected edge in at most two faces, traversed oppositely
    # (edges bucketed by their lower end, in slot order, and matched within the bucket)
    head = fo.reshape(-1)
    low = np.empty(3 * m, np.int64)
    high = np.empty(3 * m, np.int64)
    for i in range(m):
        for k in range(3):
            h, t = fo[i, k], fo[i, (k + 1) % 3]
            low[3 * i + k], high[3 * i + k] = min(h, t), max(h, t)
    start, member = _buckets(low, n)
    other = np.arange(3 * m)
    matched = np.zeros(3 * m, np.bool_)
    for x in range(n):
        if start[x + 1] - start[x] > _SMALL:  # a pole's edges: sorted by their other end
            seg = member[start[x]:start[x + 1]]
            order = np.argsort(high[seg], kind="mergesort")  # equal ends in slot order
            a = 0
            while a < order.shape[0]:
                b = a + 1
                while b < order.shape[0] and high[seg[order[b]]] == high[seg[order[a]]]:
                    b += 1
                if b - a > 2:
                    return (2,) + empty  # more than two faces
                if b - a == 2:
                    s, t = seg[order[a]], seg[order[a + 1]]
                    if head[s] == head[t]:
                        return (3,) + empty
                    other[s], other[t] = t, s
                a = b
            continue
        for p in range(start[x], start[x + 1]):
            s = member[p]
            if matched[s]:
                continue
            t = -1
            for q in range(p + 1, start[x + 1]):
                r = member[q]
                if high[r] == high[s]:
                    if t >= 0:
                        return (2,) + empty  # more than two faces
                    t = r
            if t >= 0:
                if head[s] == head[t]:  # both faces traverse it from the same corner
                    return (3,) + empty
                other[s], other[t] = t, s
                matched[t] = True
    # one pass a face: its edge vectors once; corner k's are ``a`` (to corner k+1) and ``b`` (to
    # corner k+2), the next edge and the previous one negated, which is exact, so each sum and
    # product is the one subtracting the corners gives; corner 0's cross product is the normal's
    normals, sin, cos = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3))
    e = np.empty((3, 3))
    for i in range(m):
        for k in range(3):
            p, q = fo[i, k], fo[i, (k + 1) % 3]
            for c in range(3):
                e[k, c] = vo[q, c] - vo[p, c]
        for k in range(3):
            a0, a1, a2 = e[k, 0], e[k, 1], e[k, 2]
            j = (k + 2) % 3
            b0, b1, b2 = -e[j, 0], -e[j, 1], -e[j, 2]
            x0, x1, x2 = _cross(a0, a1, a2, b0, b1, b2)
            n = np.sqrt((x0 * x0 + x1 * x1) + x2 * x2)
            sin[i, k] = n
            cos[i, k] = (a0 * b0 + a2 * b2) + a1 * b1
            if k == 0:  # `_unit_rows`
                d = n if n > 0 else 1.0
                normals[i, 0], normals[i, 1], normals[i, 2] = x0 / d, x1 / d, x2 / d
    # an inner edge's two slots sum the same two normals in either order, the same bits (addition
    # commutes), so each edge is summed and scaled once, from its lower slot
    edge_normals = np.empty((3 * m, 3))
    for s in range(3 * m):
        t = other[s]
        if t < s:
            for c in range(3):
                edge_normals[s, c] = edge_normals[t, c]
            continue
        o = t // 3
        x0, x1, x2 = normals[s // 3, 0] + normals[o, 0], normals[s // 3, 1] + normals[o, 1], normals[s // 3, 2] + normals[o, 2]
        n = np.sqrt((x0 * x0 + x1 * x1) + x2 * x2)
        d = n if n > 0 else 1.0
        edge_normals[s, 0], edge_normals[s, 1], edge_normals[s, 2] = x0 / d, x1 / d, x2 / d
    edge_normals = edge_normals.reshape(m, 3, 3)
    return 0, vo, fo, normals, edge_normals, sin, cos


@njit(cache=True, nogil=True)
def welded_part(v, f, radius, flip):
    """`part_mesh` of `weld`'s vertices and faces in one call: its ``code`` and arrays, or ``code``
    -1 (and empty arrays) where `weld` leaves a pair undecided (its ``code`` 1)."""
    code, vw, fw = weld(v, f, radius)
    if code:
        return (-1, np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)),
                np.zeros((0, 3)))
    return part_mesh(vw, fw, radius, flip)


@njit(cache=True, nogil=True)
def vertex_normals(n, faces, normals, angle):
    """Angle-weighted sums of the incident faces' normals at the ``n`` vertices, unit length:
    ``(n, 3)``, each vertex's terms summed in face order (``np.bincount``)."""
    out = np.zeros((n, 3))
    for i in range(faces.shape[0]):
        for k in range(3):
            j = faces[i, k]
            for c in range(3):
                out[j, c] += angle[i, k] * normals[i, c]
    return _unit_rows(out)


@njit(inline="always")
def _row(x, i):
    """Row ``i`` of ``x (n, 3)`` as a tuple of its 3 values. A row view handed to another compiled
    function is an array object whose reference count is taken and dropped around the call, a
    cost of the order of the arithmetic of a point-triangle test; a tuple is plain values. The
    kernels' per-point and per-face loops (closest-point walks, signs, eq. (6) and (7),
    `acra.clearcells`) read rows through it."""
    return x[i, 0], x[i, 1], x[i, 2]


@njit(inline="always")
def _corner(tri, s, k):
    """Corner ``k`` of triangle ``tri[s]`` (``tri (f, 3, 3)``) as a tuple of its 3 values (`_row`)."""
    return tri[s, k, 0], tri[s, k, 1], tri[s, k, 2]


@njit(cache=True, nogil=True, error_model="numpy")
def _signs(p, dist, close, face, bary, vertices, faces, normals, edge_normals, vertex_normals, tol, out):
    for r in range(p.shape[0]):
        f = face[r]
        a, b, c = _row(vertices, faces[f, 0]), _row(vertices, faces[f, 1]), _row(vertices, faces[f, 2])
        x0, x1, x2 = _cross(b[0] - a[0], b[1] - a[1], b[2] - a[2], c[0] - a[0], c[1] - a[1], c[2] - a[2])
        twice_area = np.sqrt((x0 * x0 + x1 * x1) + x2 * x2)
        zeros, first = 0, -1
        for k in range(3):
            q, s = _row(vertices, faces[f, (k + 2) % 3]), _row(vertices, faces[f, (k + 1) % 3])
            d0, d1, d2 = q[0] - s[0], q[1] - s[1], q[2] - s[2]
            opposite = np.sqrt((d0 * d0 + d1 * d1) + d2 * d2)
            if bary[r, k] * (twice_area / opposite) <= tol:
                zeros += 1
                if first < 0:
                    first = k
        # the normal's values read in each branch: a helper's tuple taken from one of three
        # arrays leaves that array's reference count taken and dropped per point
        if zeros == 1:
            k = (first + 1) % 3
            n0, n1, n2 = edge_normals[f, k, 0], edge_normals[f, k, 1], edge_normals[f, k, 2]
        elif zeros >= 2:
            k = 0
            for j in range(1, 3):
                if bary[r, j] > bary[r, k]:
                    k = j
            v = faces[f, k]
            n0, n1, n2 = vertex_normals[v, 0], vertex_normals[v, 1], vertex_normals[v, 2]
        else:
            n0, n1, n2 = normals[f, 0], normals[f, 1], normals[f, 2]
        e0, e1, e2 = p[r, 0] - close[r, 0], p[r, 1] - close[r, 1], p[r, 2] - close[r, 2]
        inside = (e0 * n0 + e2 * n2) + e1 * n1 < 0
        out[r] = dist[r] if inside else -dist[r]


def signs(points, dist, close, face, bary, vertices, faces, normals, edge_normals, vertex_normals, tol: float) -> np.ndarray:
    """Signed distances ``(k,)`` of ``points (k, 3)`` whose closest points ``close`` on faces
    ``face`` (barycentric ``bary``) lie at ``dist``: positive where ``(p - q) . n < 0`` with ``n``
    the pseudo-normal of the feature ``q`` lies on (a barycentric coordinate within ``tol`` of its
    edge line, scaled by the height over that edge, counts as 0), `pipeline.clearance` eq. (1)."""
    out = np.empty(len(points))
    if len(points):
        _signs(points, dist, close, face, bary, vertices, faces, normals, edge_normals, vertex_normals, float(tol), out)
    return out


@njit(cache=True, nogil=True)
def links(points, cells, limit):
    """The edges of triangles ``cells (c, 3) int64`` (rows of ``points (n, 3)``) shorter than
    ``limit``, both ways, as a CSR adjacency: ``(start (n + 1,) int64, neighbour (e,) int64,
    length (e,))``. An edge two triangles share is listed twice."""
    n = points.shape[0]
    start = np.zeros(n + 1, np.int64)
    length = np.empty((cells.shape[0], 3))
    for t in range(cells.shape[0]):
        for k in range(3):
            i, j = cells[t, k], cells[t, (k + 1) % 3]
            d0, d1, d2 = points[i, 0] - points[j, 0], points[i, 1] - points[j, 1], points[i, 2] - points[j, 2]
            length[t, k] = np.sqrt((d0 * d0 + d1 * d1) + d2 * d2)
            if i != j and length[t, k] < limit:
                start[i + 1] += 1
                start[j + 1] += 1
    for i in range(n):
        start[i + 1] += start[i]
    fill = start[:-1].copy()
    neighbour = np.empty(start[n], np.int64)
    out = np.empty(start[n])
    for t in range(cells.shape[0]):
        for k in range(3):
            i, j = cells[t, k], cells[t, (k + 1) % 3]
            if i != j and length[t, k] < limit:
                neighbour[fill[i]], out[fill[i]] = j, length[t, k]
                neighbour[fill[j]], out[fill[j]] = i, length[t, k]
                fill[i] += 1
                fill[j] += 1
    return start, neighbour, out


@njit(cache=True, nogil=True)
def flood(start, neighbour, length, seeds, sign, reach):
    """Breadth first from ``seeds (m,) int64`` over the adjacency (`links`): a point whose
    ``sign (n,) int8`` is 0 takes the sign of the point it is reached from and ``reach (n,)`` that
    point's plus the edge's length (an upper bound of its distance to the surface when the
    seeds' are). Both arrays are updated in place."""
    queue = np.empty(sign.shape[0], np.int64)
    tail = 0
    for s in range(seeds.shape[0]):
        queue[tail] = seeds[s]
        tail += 1
    head = 0
    while head < tail:
        u = queue[head]
        head += 1
        for e in range(start[u], start[u + 1]):
            w = neighbour[e]
            if sign[w] == 0:
                sign[w] = sign[u]
                reach[w] = reach[u] + length[e]
                queue[tail] = w
                tail += 1


@njit(cache=True, nogil=True)
def representatives(start, neighbour, sign):
    """The lowest row of each connected part of the points whose ``sign`` is 0 (`links`'
    adjacency): ``(r,) int64``."""
    n = sign.shape[0]
    seen = np.zeros(n, np.bool_)
    queue = np.empty(n, np.int64)
    reps = np.empty(n, np.int64)
    count = 0
    for i in range(n):
        if sign[i] != 0 or seen[i]:
            continue
        reps[count] = i
        count += 1
        seen[i] = True
        queue[0] = i
        head, tail = 0, 1
        while head < tail:
            u = queue[head]
            head += 1
            for e in range(start[u], start[u + 1]):
                w = neighbour[e]
                if sign[w] == 0 and not seen[w]:
                    seen[w] = True
                    queue[tail] = w
                    tail += 1
    return reps[:count]
