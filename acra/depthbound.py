"""The residual's branch and bound in one compiled call: how deep a set of triangles reaches
inside a solid, as a certified upper bound (`depth`).

`pipeline.clearance.triangle_depth` states the bound: the corners' signed distances (eq. (1),
signs by `acra.pseudonormals.signs`), each cell's covering radius (eq. (3), `covering_radii`),
eq. (4)'s bound from them, eq. (6)'s facet bound (`facet_bound`) and, on a convex solid, eq. (7)'s
plane bound; cells whose bound could still be the maximum split into four (`children`, on a
dyadic lattice of the triangle, `lattice_points`), deduplicated by their points' bits. Here that
whole loop runs compiled: corners and each level's midpoints searched by the tree's walk
(`acra.bvh`), each step in the arithmetic and order of the array form in `pipeline.clearance`,
so the answers are the same bits (`tests/test_clearance.py` holds them), without a numpy call per
step of a level.

Arrays are float64 unless stated.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from acra.bvh import Tree, _closest, _point_triangle
from acra.meshrows import _boxes_meet, _distinct_rows
from acra.pseudonormals import _row, _signs, flood as _flood, links as _links, representatives as _representatives

__all__ = ["facet_bound", "covering_radii", "children", "lattice_points", "depth"]


@njit(cache=True, nogil=True)
def _cell_facet_bound(cell, f0, f1, f2, vertices, solid_faces, facet, facet_start, facet_faces, tri, least, o0, o1, o2, cap):
    """Eq. (6) of one cell ``cell (3, 3)`` whose corners' closest faces are ``f0, f1, f2``, with
    scratch ``tri (3, 3)`` and ``least (3,)``, as ``min(cap, eq. (6))``: each facet's faces gathered
    once, all three corners measured against each; a facet two corners share is measured once (min
    and max are exact, so the order is free). ``o0, o1, o2``: each corner's distance to its closest
    face where known (the walk's, the same arithmetic, so the same bits), else negative: a facet of
    that face alone needs no second measure of its corner. A facet whose first measured corner is
    already at least the smaller of ``cap`` and the facets before cannot lower the minimum, so its
    other corners are not measured."""
    best = cap
    for j in range(3):
        fj = f0 if j == 0 else (f1 if j == 1 else f2)
        g = facet[fj]
        if (j > 0 and facet[f0] == g) or (j > 1 and facet[f1] == g):
            continue
        s0, s1 = facet_start[g], facet_start[g + 1]
        oj = o0 if j == 0 else (o1 if j == 1 else o2)
        if s1 - s0 == 1 and oj >= 0.0:
            # the facet is corner j's face alone: its distance is known, and one corner at least
            # the minimum so far decides the facet; the others are measured only if needed
            top = oj
            if not top < best:
                continue
            m = facet_faces[s0]
            for k in range(3):
                for q in range(3):
                    tri[k, q] = vertices[solid_faces[m, k], q]
            for i in range(3):
                if i == j:
                    continue
                fi = f0 if i == 0 else (f1 if i == 1 else f2)
                oi = o0 if i == 0 else (o1 if i == 1 else o2)
                if fi == m and oi >= 0.0:
                    d = oi
                else:
                    x, y, z, _, _, _ = _point_triangle(_row(cell, i), _row(tri, 0), _row(tri, 1), _row(tri, 2))
                    d = np.sqrt((cell[i, 0] - x) ** 2 + (cell[i, 1] - y) ** 2 + (cell[i, 2] - z) ** 2)
                top = max(top, d)
                if not top < best:
                    break
            best = min(best, top)
            continue
        least[0], least[1], least[2] = np.inf, np.inf, np.inf
        for s in range(s0, s1):
            m = facet_faces[s]
            for k in range(3):
                # element by element: a row assigned from an array would compile numba's
                # shape-mismatch message (its string formatting) into the first run
                for q in range(3):
                    tri[k, q] = vertices[solid_faces[m, k], q]
            for i in range(3):
                x, y, z, _, _, _ = _point_triangle(_row(cell, i), _row(tri, 0), _row(tri, 1), _row(tri, 2))
                d = np.sqrt((cell[i, 0] - x) ** 2 + (cell[i, 1] - y) ** 2 + (cell[i, 2] - z) ** 2)
                least[i] = min(least[i], d)
        best = min(best, max(max(least[0], least[1]), least[2]))
    return best


@njit(cache=True, nogil=True)
def _facet_bound(cells, faces, vertices, solid_faces, facet, facet_start, facet_faces, out):
    tri = np.empty((3, 3))
    least = np.empty(3)
    for c in range(cells.shape[0]):
        out[c] = _cell_facet_bound(cells[c], faces[c, 0], faces[c, 1], faces[c, 2], vertices, solid_faces, facet,
                                   facet_start, facet_faces, tri, least, -1.0, -1.0, -1.0, np.inf)


def facet_bound(cells: np.ndarray, faces: np.ndarray, vertices: np.ndarray, solid_faces: np.ndarray, facet: np.ndarray,
                facet_start: np.ndarray, facet_faces: np.ndarray) -> np.ndarray:
    """``min_j max_i dist(c_i, P_j)`` ``(c,) float64`` for cells ``(c, 3, 3)`` whose corners' closest
    faces are ``faces (c, 3) int64``, ``P_j`` the convex facet (faces ``facet_faces[facet_start[g]
    : facet_start[g + 1]]``, ``g = facet[face]``) of corner ``j``'s face, a distance to a facet
    the least to its faces (`distances`' arithmetic)."""
    out = np.empty(len(cells))
    if len(cells):
        _facet_bound(np.ascontiguousarray(cells, np.float64), np.ascontiguousarray(faces, np.int64), vertices,
                     solid_faces, facet, facet_start, facet_faces, out)
    return out


@njit(cache=True, nogil=True)
def _covering_radii(tri, out):
    sq = np.empty(3)
    e = np.empty((3, 3))
    for i in range(tri.shape[0]):
        for k in range(3):
            for c in range(3):
                e[k, c] = tri[i, (k + 1) % 3, c] - tri[i, k, c]
            sq[k] = (e[k, 0] ** 2 + e[k, 1] ** 2) + e[k, 2] ** 2
        k = 0
        for j in range(1, 3):
            if sq[j] > sq[k]:
                k = j
        ab, bc, ca = sq[k], sq[(k + 1) % 3], sq[(k + 2) % 3]
        b0, b1, b2 = -e[2, 0], -e[2, 1], -e[2, 2]
        x0 = e[0, 1] * b2 - e[0, 2] * b1
        x1 = e[0, 2] * b0 - e[0, 0] * b2
        x2 = e[0, 0] * b1 - e[0, 1] * b0
        twice_area = np.sqrt((x0 * x0 + x1 * x1) + x2 * x2)
        if ab > bc + ca or twice_area == 0:
            dot_a, dot_b = 0.5 * ((ab + ca) - bc), 0.5 * ((ab + bc) - ca)
            root = np.sqrt(ab)
            from_a = ca * root / (2 * dot_a) if dot_a > 0 else 0.0
            from_b = bc * root / (2 * dot_b) if dot_b > 0 else 0.0
            out[i] = max(from_a, from_b)
        else:
            out[i] = np.sqrt(ab * bc * ca) / (2 * twice_area)


def covering_radii(tri: np.ndarray) -> np.ndarray:
    """`pipeline.clearance.covering_radius` of triangles ``tri (t, 3, 3)``, compiled: ``(t,)``, each
    step in the order of its numpy form (a sum of 3 squares as ``(x0² + x1²) + x2²``, ``np.cross``
    as ``a1 b2 - a2 b1``)."""
    t = np.ascontiguousarray(tri, np.float64).reshape(-1, 3, 3)
    out = np.empty(len(t))
    if len(t):
        _covering_radii(t, out)
    return out


_CHILDREN = ((0, 3, 5), (3, 1, 4), (5, 4, 2), (3, 4, 5))  # of corners c0, c1, c2, m01, m12, m20


@njit(cache=True, nogil=True)
def _children(lattice, mid, sd, sd_mid, fc, face_mid, inverse, rows, rho, out_lat, out_sd, out_fc, out_rows, out_rho):
    c = lattice.shape[0]
    for q in range(4):
        pick = _CHILDREN[q]
        for i in range(c):
            o = q * c + i
            for j in range(3):
                k = pick[j]
                if k < 3:
                    for w in range(3):
                        out_lat[o, j, w] = lattice[i, k, w]
                    out_sd[o, j], out_fc[o, j] = sd[i, k], fc[i, k]
                else:
                    for w in range(3):
                        out_lat[o, j, w] = mid[i, k - 3, w]
                    u = inverse[3 * i + k - 3]
                    out_sd[o, j], out_fc[o, j] = sd_mid[u], face_mid[u]
            out_rows[o], out_rho[o] = rows[i], 0.5 * rho[i]


def children(lattice: np.ndarray, mid: np.ndarray, sd: np.ndarray, sd_mid: np.ndarray, fc: np.ndarray,
             face_mid: np.ndarray, inverse: np.ndarray, rows: np.ndarray, rho: np.ndarray):
    """The four children of each of ``c`` cells split at their edge midpoints, child by child
    (all cells' first children, then their second, ...): of corners ``(c0, m01, m20), (m01, c1,
    m12), (m20, m12, c2), (m01, m12, m20)``, with the cells' ``lattice (c, 3, 3) int64``, corner
    depths ``sd (c, 3)`` and faces ``fc (c, 3) int64``, the midpoints' ``mid (c, 3, 3) int64``
    and, for midpoint ``k`` of cell ``i``, depth and face ``sd_mid[u]``, ``face_mid[u]`` with ``u
    = inverse[3 i + k]``; each child's ``rows`` its parent's and its covering radius half the
    parent's ``rho``. Returns ``(lattice (4c, 3, 3), sd (4c, 3), fc (4c, 3), rows (4c,), rho
    (4c,))``."""
    c = len(lattice)
    out = (np.empty((4 * c, 3, 3), np.int64), np.empty((4 * c, 3)), np.empty((4 * c, 3), np.int64),
           np.empty(4 * c, np.int64), np.empty(4 * c))
    if c:
        _children(np.ascontiguousarray(lattice, np.int64), np.ascontiguousarray(mid, np.int64),
                  np.ascontiguousarray(sd, np.float64), np.ascontiguousarray(sd_mid, np.float64),
                  np.ascontiguousarray(fc, np.int64), np.ascontiguousarray(face_mid, np.int64),
                  np.ascontiguousarray(inverse, np.int64), np.ascontiguousarray(rows, np.int64),
                  np.ascontiguousarray(rho, np.float64), *out)
    return out


@njit(cache=True, nogil=True)
def _lattice_points(tri, owner, lattice, steps, out):
    for r in range(lattice.shape[0]):
        t = owner[r // 3]
        w0, w1, w2 = lattice[r, 0] / steps, lattice[r, 1] / steps, lattice[r, 2] / steps
        for c in range(3):
            out[r, c] = (w0 * tri[t, 0, c] + w1 * tri[t, 1, c]) + w2 * tri[t, 2, c]


def lattice_points(tri: np.ndarray, owner: np.ndarray, lattice: np.ndarray, steps: int) -> np.ndarray:
    """Points ``(3c, 3)`` at integer barycentric weights ``lattice (c, 3, 3) int64`` (per cell,
    three rows of weights times ``steps``) in the triangles ``tri[owner] (c, 3, 3)``: each weight
    ``lattice / steps`` and the point ``w0 a + w1 b + w2 c`` summed corner by corner, as
    `pipeline.clearance._at` computes them in numpy, without its gathered copies."""
    lat = np.ascontiguousarray(lattice, np.int64).reshape(-1, 3)
    out = np.empty((len(lat), 3))
    if len(lat):
        _lattice_points(np.ascontiguousarray(tri, np.float64), np.ascontiguousarray(owner, np.int64), lat, steps, out)
    return out


_NO_PLANES = np.full(1, -1, np.int64)  # `depth` without eq. (7): not a convex solid


@njit(cache=True, nogil=True)
def _cell_bound(cell, f0, f1, f2, vertices, faces, normals, facet, facet_start, facet_faces, planes, scratch, least, sd, cap):
    """`pipeline.clearance._cell_bound` of one cell ``cell (3, 3)`` whose corners' closest faces are
    ``f0, f1, f2`` and signed depths ``sd`` (3 floats: their magnitudes the walks' distances, or
    ``-inf`` where not found), no larger than ``cap`` (the cell's eq. (4), which the caller keeps
    if smaller): ``min(cap, eq. (6))``, and on a convex solid (``planes`` not `_NO_PLANES`) the
    smaller of it and eq. (7), ``min_j max_i max(0, (a_j - c_i) . n_j)`` over the planes of the
    faces ``planes`` (every facet's), or of ``f0, f1, f2`` if ``planes`` is empty. A dot product of
    3 terms is summed as ``(p0 + p2) + p1``, as ``np.einsum`` sums it in the array form."""
    # a corner's own distance, where its walk found it
    o0 = abs(sd[0]) if f0 >= 0 and abs(sd[0]) < np.inf else -1.0
    o1 = abs(sd[1]) if f1 >= 0 and abs(sd[1]) < np.inf else -1.0
    o2 = abs(sd[2]) if f2 >= 0 and abs(sd[2]) < np.inf else -1.0
    out = _cell_facet_bound(cell, f0, f1, f2, vertices, faces, facet, facet_start, facet_faces, scratch, least, o0, o1, o2, cap)
    if planes.shape[0] == 1 and planes[0] < 0:
        return out
    g = planes.shape[0] if planes.shape[0] else 3
    plane = np.inf
    for j in range(g):
        row = planes[j] if planes.shape[0] else (f0 if j == 0 else (f1 if j == 1 else f2))
        a = _row(vertices, faces[row, 0])
        n = _row(normals, row)
        d = (a[0] * n[0] + a[2] * n[2]) + a[1] * n[1]
        top = 0.0
        for i in range(3):
            x = d - ((cell[i, 0] * n[0] + cell[i, 2] * n[2]) + cell[i, 1] * n[1])
            if x > top:
                top = x
        if top < plane:
            plane = top
    return plane if plane < out else out


@njit(cache=True, nogil=True)
def _cell_corners(tri, t, lattice, i, steps, out):
    """The corners ``out (3, 3)`` of cell ``i`` of source triangle ``tri[t]`` at integer barycentric
    ``lattice[i] (3, 3)``, in `_lattice_points`' arithmetic."""
    for r in range(3):
        w0, w1, w2 = lattice[i, r, 0] / steps, lattice[i, r, 1] / steps, lattice[i, r, 2] / steps
        for c in range(3):
            out[r, c] = (w0 * tri[t, 0, c] + w1 * tri[t, 1, c]) + w2 * tri[t, 2, c]


@njit(cache=True, nogil=True)
def _signed_at(points, ids, reach, leaf_tri, order, lo, hi, left, right, start, count, vertices, faces, normals,
               edge_normals, vertex_normals, tol, sd, face):
    """Eq. (1) at ``points[ids]`` (closest points within ``reach``, `_closest`; their signs,
    `acra.pseudonormals.signs`) into ``sd[ids]`` and ``face[ids]``: False if one has no face within
    ``reach`` (the arrays then partly written). A point's answer does not depend on the others
    queried with it."""
    k = ids.shape[0]
    if k == 0:
        return True
    p = np.empty((k, 3))
    for r in range(k):
        for c in range(3):
            p[r, c] = points[ids[r], c]
    dist, close = np.full(k, np.inf), np.zeros((k, 3))
    near, bary = np.full(k, -1, np.int64), np.zeros((k, 3))
    _closest(leaf_tri, order, lo, hi, left, right, start, count, p, np.full(k, reach), dist, close, near, bary)
    for r in range(k):
        if near[r] < 0:
            return False
    out = np.empty(k)
    _signs(p, dist, close, near, bary, vertices, faces, normals, edge_normals, vertex_normals, tol, out)
    for r in range(k):
        sd[ids[r]], face[ids[r]] = out[r], near[r]
    return True


@njit(cache=True, nogil=True)
def _sortable(key):
    """``key (k,) float64`` (no NaN) as int64 values in the same order, in place: a stable sort
    of them is the stable sort of ``key`` (equal values, -0.0 and 0.0 among them, stay equal).
    int64 is the one key type every kernel's merge sort takes, so a first run compiles numba's
    argsort once (a float64 key costs about 1.2 s CPU more)."""
    for j in range(key.shape[0]):
        key[j] = key[j] + 0.0  # -0.0 as 0.0
    bits = key.view(np.int64)
    for j in range(bits.shape[0]):
        if bits[j] < 0:  # negative: larger magnitudes first
            bits[j] ^= 0x7FFFFFFFFFFFFFFF
    return bits


@njit(cache=True, nogil=True)
def _refine(tri, src, rows, lattice, sd, fc, rho, bound, low, target, decide, steps, max_split, budget, evaluated, reach,
            leaf_tri, order, lo, hi, left, right, start, count, vertices, faces, normals, edge_normals, vertex_normals,
            tol, facet, facet_start, facet_faces, planes, stop):
    # `pipeline.clearance`'s branch and bound from level 0 on, the level-0 cells' eq. (4) given
    # as ``bound``; each step in the arithmetic and order of its array form (`_levels`),
    # so the answers are the same bits. A level whose points reach deeper than ``stop`` ends the
    # search (code 2): the caller asks only whether the depth exceeds it. A maximum is exact whatever the order of its terms, so
    # the retired cells' eq. (6) is taken one cell at a time, largest eq. (4) first, until the
    # next cannot raise it. Python's ``max(a, b)`` keeps ``a`` unless ``b > a``: written out
    # below, a signed zero comes out as it does there.
    cell = np.empty((3, 3))
    scratch = np.empty((3, 3))
    least = np.empty(3)
    cap, m = 256, 0
    found_tri = np.empty(cap, np.int64)
    found_lat = np.empty((cap, 3), np.int64)
    found_pts = np.empty((cap, 3))
    found_sd = np.empty(cap)
    retired, level, complete = 0.0, 0, True
    c = rows.shape[0]
    first_pass = True
    while c > 0:
        top0 = low if low > 0.0 else 0.0
        now = target if not (1.25 * top0 > target) else 1.25 * top0
        if not first_pass:
            for i in range(c):
                a = sd[i, 0] if sd[i, 0] > sd[i, 1] else sd[i, 1]
                a = a if a > sd[i, 2] else sd[i, 2]
                v = a + rho[i]
                bound[i] = v if v > 0.0 else 0.0
        first_pass = False
        need = np.empty(c, np.bool_)
        late = np.empty(c, np.int64)  # cells eq. (4) retires above 0: eq. (6) only if they could raise the maximum
        n_late = 0
        for i in range(c):
            b = bound[i]
            split = b > now or (b > decide and low <= decide)
            if b > 0.0 and split:
                _cell_corners(tri, src[rows[i]], lattice, i, steps, cell)
                six = _cell_bound(cell, fc[i, 0], fc[i, 1], fc[i, 2], vertices, faces, normals, facet, facet_start, facet_faces,
                                  planes, scratch, least, _row(sd, i), b)
                if six < b:
                    b = six
                    bound[i] = b
            keep = b > now or (b > decide and low <= decide)
            need[i] = keep
            if split and not keep and b > retired:
                retired = b
            elif b > 0.0 and not split:
                late[n_late] = i
                n_late += 1
        # `retired` only grows, so a cell at or below it now can never raise it: those are left out
        # of the sort (the rest keep their order, so the cells taken and their order are the same)
        above = 0
        for j in range(n_late):
            if bound[late[j]] > retired:
                late[above] = late[j]
                above += 1
        n_late = above
        if n_late:
            late = late[:n_late]
            key = np.empty(n_late)
            for j in range(n_late):
                key[j] = -bound[late[j]]
            for j in np.argsort(_sortable(key), kind="mergesort"):
                i = late[j]
                if not bound[i] > retired:
                    break
                _cell_corners(tri, src[rows[i]], lattice, i, steps, cell)
                six = _cell_bound(cell, fc[i, 0], fc[i, 1], fc[i, 2], vertices, faces, normals, facet, facet_start, facet_faces,
                                  planes, scratch, least, _row(sd, i), bound[i])
                b = six if six < bound[i] else bound[i]
                if b > retired:
                    retired = b
        kept = 0
        for i in range(c):
            if need[i]:
                kept += 1
        pick = np.empty(kept, np.int64)
        kept = 0
        for i in range(c):
            if need[i]:
                pick[kept] = i
                kept += 1
        room = (budget - evaluated) // 3
        if kept == 0 or level == max_split or room <= 0:
            complete = kept == 0
            for i in pick:
                if bound[i] > retired:
                    retired = bound[i]
            break
        if room < kept:  # the budget's last pass: the cells of largest bound
            key = np.empty(kept)
            for j in range(kept):
                key[j] = -bound[pick[j]]
            rank = np.argsort(_sortable(key), kind="mergesort")
            for j in rank[room:]:
                if bound[pick[j]] > retired:
                    retired = bound[pick[j]]
            pick = pick[rank[:room]]
            kept = room
            complete = False
        c = kept
        rows_k, lat_k, sd_k, fc_k, rho_k = (np.empty(c, np.int64), np.empty((c, 3, 3), np.int64), np.empty((c, 3)),
                                            np.empty((c, 3), np.int64), np.empty(c))
        mid = np.empty((c, 3, 3), np.int64)  # midpoints of edges (0,1), (1,2), (2,0); lattice steps here are even
        owner = np.empty(c, np.int64)
        for j in range(c):
            i = pick[j]
            rows_k[j], rho_k[j] = rows[i], rho[i]
            owner[j] = src[rows[i]]
            for k in range(3):
                sd_k[j, k], fc_k[j, k] = sd[i, k], fc[i, k]
                for w in range(3):
                    lat_k[j, k, w] = lattice[i, k, w]
            for k in range(3):
                for w in range(3):
                    mid[j, k, w] = (lat_k[j, k, w] + lat_k[j, (k + 1) % 3, w]) // 2
        flat = mid.reshape(3 * c, 3)
        at = np.empty((3 * c, 3))
        _lattice_points(tri, owner, flat, steps, at)
        first = np.empty(3 * c, np.int64)
        inverse = np.empty(3 * c, np.int64)
        u = _distinct_rows(at.view(np.uint64), first, inverse)
        pts = np.empty((u, 3))
        for r in range(u):
            for k in range(3):
                pts[r, k] = at[first[r], k]
        sd_mid, face = np.empty(u), np.empty(u, np.int64)
        if not _signed_at(pts, np.arange(u), reach, leaf_tri, order, lo, hi, left, right, start, count, vertices, faces,
                          normals, edge_normals, vertex_normals, tol, sd_mid, face):  # farther than the part answers for
            return (1, retired, low, False, evaluated, level, found_tri[:m], found_lat[:m], found_pts[:m],
                    found_sd[:m])
        evaluated += u
        inside = 0
        deepest = -np.inf
        for r in range(u):
            if sd_mid[r] > 0:
                inside += 1
            if sd_mid[r] > deepest:
                deepest = sd_mid[r]
        if m + inside > cap:
            cap = max(2 * cap, m + inside)
            grown_tri, grown_lat, grown_pts, grown_sd = (np.empty(cap, np.int64), np.empty((cap, 3), np.int64),
                                                         np.empty((cap, 3)), np.empty(cap))
            for r in range(m):  # element by element: a slice assigned from an array would compile numba's
                # shape check and its message's string formatting into the first run (about 2 s CPU)
                grown_tri[r], grown_sd[r] = found_tri[r], found_sd[r]
                for k in range(3):
                    grown_lat[r, k], grown_pts[r, k] = found_lat[r, k], found_pts[r, k]
            found_tri, found_lat, found_pts, found_sd = grown_tri, grown_lat, grown_pts, grown_sd
        for r in range(u):
            if sd_mid[r] > 0:
                found_tri[m] = owner[first[r] // 3]
                for k in range(3):
                    found_lat[m, k] = flat[first[r], k]
                    found_pts[m, k] = pts[r, k]
                found_sd[m] = sd_mid[r]
                m += 1
        if deepest > low:
            low = deepest
        if low > stop:  # a point deeper than ``stop`` answers the caller: the cells are left
            return 2, low, low, False, evaluated, level, found_tri[:m], found_lat[:m], found_pts[:m], found_sd[:m]
        # children (c0, m01, m20), (m01, c1, m12), (m20, m12, c2), (m01, m12, m20), child by child
        lattice, sd, fc, rows, rho = (np.empty((4 * c, 3, 3), np.int64), np.empty((4 * c, 3)),
                                      np.empty((4 * c, 3), np.int64), np.empty(4 * c, np.int64), np.empty(4 * c))
        _children(lat_k, mid, sd_k, sd_mid, fc_k, face, inverse, rows_k, rho_k, lattice, sd, fc, rows, rho)
        c = 4 * c
        bound = np.empty(c)
        level += 1
        if not complete:  # the budget's last pass: bound the children and stop
            last = 0.0
            for i in range(c):
                a = sd[i, 0] if sd[i, 0] > sd[i, 1] else sd[i, 1]
                a = a if a > sd[i, 2] else sd[i, 2]
                v = a + rho[i]
                if v > 0.0:
                    _cell_corners(tri, src[rows[i]], lattice, i, steps, cell)
                    six = _cell_bound(cell, fc[i, 0], fc[i, 1], fc[i, 2], vertices, faces, normals, facet, facet_start, facet_faces,
                                      planes, scratch, least, _row(sd, i), v)
                    v = six if six < v else v
                    if v > last:
                        last = v
            if last > retired:
                retired = last
            top0 = low if low > 0.0 else 0.0
            now = target if not (1.25 * top0 > target) else 1.25 * top0
            complete = retired <= now and not (decide < retired and low <= decide)
            break
    return 0, retired, low, complete, evaluated, level, found_tri[:m], found_lat[:m], found_pts[:m], found_sd[:m]


@njit(cache=True, nogil=True)
def _depth(tri, box_lo, box_hi, part, reach, target, decide, max_split, budget, far, link, leaf_tri, order, lo, hi, left,
           right, start, count, vertices, faces, normals, edge_normals, vertex_normals, tol, facet, facet_start,
           facet_faces, planes, stop):
    # `pipeline.clearance._triangle_depth`'s level 0 (its corners, `_signed_corners`) in the
    # arithmetic and order of its array form, then the levels past it (`_refine`); a corner
    # deeper than ``stop`` ends the search there (code 2, the corners found inside)
    steps = 1 << max_split
    t = tri.shape[0]
    meet = np.empty(t, np.bool_)
    _boxes_meet(tri, box_lo, box_hi, reach if part else 0.0, meet)
    n_live = 0
    for i in range(t):
        if meet[i]:
            n_live += 1
        elif part:  # beyond reach of the part's box: farther than the part answers for
            return 1, 0.0, -np.inf, False, 0, 0, np.empty(0, np.int64), np.empty((0, 3), np.int64), np.empty((0, 3)), np.empty(0)
    c = n_live
    src = np.empty(c, np.int64)
    live = np.empty((c, 3, 3))
    n_live = 0
    for i in range(t):
        if meet[i]:
            src[n_live] = i
            for k in range(3):
                for q in range(3):
                    live[n_live, k, q] = tri[i, k, q]
            n_live += 1
    rho = np.empty(c)
    if c:
        _covering_radii(live, rho)
    corners = live.reshape(3 * c, 3)
    first, inverse = np.empty(3 * c, np.int64), np.empty(3 * c, np.int64)
    u = _distinct_rows(corners.view(np.uint64), first, inverse) if c else 0
    pts = np.empty((u, 3))
    for r in range(u):
        for q in range(3):
            pts[r, q] = corners[first[r], q]
    cell_pts = inverse.reshape(c, 3)
    sd_pts, face_pts = np.empty(u), np.full(u, -1, np.int64)
    pending = np.zeros(u, np.bool_)
    has_pending = False
    # `_signed_corners`
    largest = 0.0
    for i in range(c):
        if rho[i] > largest:
            largest = rho[i]
    q_far = far * largest
    if reach < q_far:
        q_far = reach
    if u == 0 or not q_far >= largest or not q_far > 0:
        if not _signed_at(pts, np.arange(u), reach, leaf_tri, order, lo, hi, left, right, start, count, vertices, faces,
                          normals, edge_normals, vertex_normals, tol, sd_pts, face_pts):
            return 1, 0.0, -np.inf, False, 0, 0, np.empty(0, np.int64), np.empty((0, 3), np.int64), np.empty((0, 3)), np.empty(0)
    else:
        dist, close, bary = np.full(u, np.inf), np.zeros((u, 3)), np.zeros((u, 3))
        _closest(leaf_tri, order, lo, hi, left, right, start, count, pts, np.full(u, q_far), dist, close, face_pts, bary)
        n_known = 0
        for r in range(u):
            if face_pts[r] >= 0:
                n_known += 1
        known = np.empty(n_known, np.int64)
        n_known = 0
        for r in range(u):
            sd_pts[r] = -np.inf
            if face_pts[r] >= 0:
                known[n_known] = r
                n_known += 1
        kp, kd, kc, kf, kb = (np.empty((n_known, 3)), np.empty(n_known), np.empty((n_known, 3)), np.empty(n_known, np.int64),
                              np.empty((n_known, 3)))
        for j in range(n_known):
            r = known[j]
            kd[j], kf[j] = dist[r], face_pts[r]
            for q in range(3):
                kp[j, q], kc[j, q], kb[j, q] = pts[r, q], close[r, q], bary[r, q]
        signed = np.empty(n_known)
        _signs(kp, kd, kc, kf, kb, vertices, faces, normals, edge_normals, vertex_normals, tol, signed)
        for j in range(n_known):
            sd_pts[known[j]] = signed[j]
        if n_known < u:
            sign = np.zeros(u, np.int8)
            ub = np.full(u, np.inf)
            for j in range(n_known):
                r = known[j]
                sign[r] = 1 if sd_pts[r] > 0 else -1
                ub[r] = dist[r]
            adj_start, neighbour, length = _links(pts, cell_pts, link * q_far)
            _flood(adj_start, neighbour, length, known, sign, ub)
            reps = _representatives(adj_start, neighbour, sign)
            if len(reps):  # a group of far corners no near corner reaches: one of each exactly
                if not _signed_at(pts, reps, reach, leaf_tri, order, lo, hi, left, right, start, count, vertices, faces,
                                  normals, edge_normals, vertex_normals, tol, sd_pts, face_pts):
                    return (1, 0.0, -np.inf, False, 0, 0, np.empty(0, np.int64), np.empty((0, 3), np.int64), np.empty((0, 3)),
                            np.empty(0))
                for r in reps:
                    sign[r] = 1 if sd_pts[r] > 0 else -1
                    ub[r] = abs(sd_pts[r])
                _flood(adj_start, neighbour, length, reps, sign, ub)
            n_exact = 0
            exact = np.empty(u, np.int64)
            for r in range(u):
                if face_pts[r] < 0 and (sign[r] > 0 or ub[r] > reach):
                    exact[n_exact] = r
                    n_exact += 1
            if n_exact:
                if not _signed_at(pts, exact[:n_exact], reach, leaf_tri, order, lo, hi, left, right, start, count, vertices,
                                  faces, normals, edge_normals, vertex_normals, tol, sd_pts, face_pts):
                    return (1, 0.0, -np.inf, False, 0, 0, np.empty(0, np.int64), np.empty((0, 3), np.int64), np.empty((0, 3)),
                            np.empty(0))
            for r in range(u):
                if face_pts[r] < 0:
                    pending[r] = True
                    has_pending = True
    # the corners found inside, and the deepest
    n_in = 0
    low = -np.inf
    for r in range(u):
        if sd_pts[r] > 0:
            n_in += 1
        if r == 0 or sd_pts[r] > low:
            low = sd_pts[r]
    in_tri, in_lat, in_pts, in_sd = np.empty(n_in, np.int64), np.zeros((n_in, 3), np.int64), np.empty((n_in, 3)), np.empty(n_in)
    n_in = 0
    for r in range(u):
        if sd_pts[r] > 0:
            in_tri[n_in] = src[first[r] // 3]
            in_lat[n_in, first[r] % 3] = steps
            for q in range(3):
                in_pts[n_in, q] = pts[r, q]
            in_sd[n_in] = sd_pts[r]
            n_in += 1
    if c == 0:
        return 0, 0.0, low, True, u, 0, in_tri, in_lat, in_pts, in_sd
    if low > stop:
        return 2, low, low, False, u, 0, in_tri, in_lat, in_pts, in_sd
    lattice = np.zeros((c, 3, 3), np.int64)
    sd, fc = np.empty((c, 3)), np.empty((c, 3), np.int64)
    bound = np.empty(c)
    for i in range(c):
        for k in range(3):
            lattice[i, k, k] = steps
            sd[i, k], fc[i, k] = sd_pts[cell_pts[i, k]], face_pts[cell_pts[i, k]]
        a = sd[i, 0] if sd[i, 0] > sd[i, 1] else sd[i, 1]
        a = a if a > sd[i, 2] else sd[i, 2]
        v = a + rho[i]
        bound[i] = v if v > 0.0 else 0.0
    if has_pending:  # eq. (6) needs the nearest faces of the far corners of cells above 0
        wanted = np.zeros(u, np.bool_)
        for i in range(c):
            if bound[i] > 0.0:
                for k in range(3):
                    wanted[cell_pts[i, k]] = True
        n_ids = 0
        ids = np.empty(u, np.int64)
        for r in range(u):
            if wanted[r] and pending[r]:
                ids[n_ids] = r
                n_ids += 1
        if n_ids:
            if not _signed_at(pts, ids[:n_ids], reach, leaf_tri, order, lo, hi, left, right, start, count, vertices, faces,
                              normals, edge_normals, vertex_normals, tol, sd_pts, face_pts):
                return 1, 0.0, -np.inf, False, 0, 0, np.empty(0, np.int64), np.empty((0, 3), np.int64), np.empty((0, 3)), np.empty(0)
            for i in range(c):
                for k in range(3):
                    sd[i, k], fc[i, k] = sd_pts[cell_pts[i, k]], face_pts[cell_pts[i, k]]
    code, retired, low, complete, evaluated, level, f_tri, f_lat, f_pts, f_sd = _refine(
        tri, src, np.arange(c), lattice, sd, fc, rho, bound, low, target, decide, steps, max_split, budget, u, reach,
        leaf_tri, order, lo, hi, left, right, start, count, vertices, faces, normals, edge_normals, vertex_normals, tol,
        facet, facet_start, facet_faces, planes, stop)
    return (code, retired, low, complete, evaluated, level, np.concatenate((in_tri, f_tri)), np.concatenate((in_lat, f_lat)),
            np.concatenate((in_pts, f_pts)), np.concatenate((in_sd, f_sd)))


def depth(tri, box, part: bool, reach: float, target: float, decide: float, max_split: int, budget: int, far: float,
          link: float, tree: Tree, vertices, faces, normals, edge_normals, vertex_normals, tol: float, facet, facet_start,
          facet_faces, planes=None, stop: float = np.inf):
    """`pipeline.clearance.triangle_depth`'s branch and bound of triangles ``tri (t, 3, 3)`` in one
    compiled call, the same bits as its array form: the triangles whose boxes meet ``box (2, 3)``
    (within ``reach`` on a ``part``, where every triangle must), their corners signed (far ones
    by their neighbours: ``far`` and ``link``, `_signed_corners`), then the levels, against the
    solid's ``tree``, mesh, pseudo-normals (`acra.pseudonormals.signs` with ``tol``) and facets
    (``tree`` built from ``vertices[faces]``, as `build_linear` builds it, so a corner's walk
    distance is the bits eq. (6) measures to the same face).
    ``reach``: points farther from every face are unresolved. ``planes``: on a convex solid, eq.
    (7) bounds cells too (`_cell_bound`): ``(0,) int64`` for each corner's closest face's plane,
    else ``(g,) int64`` the faces whose planes bound every cell (one of each facet); ``None``
    for no eq. (7).

    ``stop``: the search ends at the first level (the corners, then each split's midpoints)
    whose points reach deeper than it, for a caller that asks only whether the depth exceeds it
    (a tolerance): every step before is the full search's, so the points found are the first of
    the full search's, bit for bit, and no later step is taken. ``inf``: the full search.

    Returns ``None`` if a point is unresolved, else ``(bound, low, complete, evaluated, level,
    tri (m,) int64, lattice (m, 3) int64, points (m, 3), depth (m,), stopped)``: the certified
    bound, the largest depth found (``-inf`` if no point), whether every cell ended within its
    target, the points evaluated, the split depth, the points found inside, in order, with their
    integer barycentric weights (times ``1 << max_split``), and whether ``stop`` ended the
    search (``bound`` is then ``low``, a lower bound only, and ``complete`` is False)."""
    out = _depth(np.ascontiguousarray(tri, np.float64).reshape(-1, 3, 3), np.ascontiguousarray(box[0], np.float64),
                 np.ascontiguousarray(box[1], np.float64), bool(part), float(reach), float(target), float(decide),
                 int(max_split), int(budget), float(far), float(link), tree.leaf_tri, tree.order, tree.lo, tree.hi, tree.left,
                 tree.right, tree.start, tree.count, vertices, faces, normals, edge_normals, vertex_normals, float(tol), facet,
                 facet_start, facet_faces, _NO_PLANES if planes is None else np.ascontiguousarray(planes, np.int64),
                 float(stop))
    return None if out[0] == 1 else out[1:] + (out[0] == 2,)
