"""Exact closest points on a triangle set through a bounding volume hierarchy, compiled.

The residual a user sees is measured by signed distances from display points to another
object's display mesh (`pipeline.clearance`): one exact closest point per query. Over a mesh of
10^4–10^5 triangles whose sizes differ by the hierarchy's levels, kd-tree balls over triangle
centroids hold hundreds of candidates per query; a BVH visits the few boxes nearer than the best
triangle found so far, and a compiled loop makes each visit cost nanoseconds instead of a numpy
call's microseconds.

The tree (`build`) splits each node's triangles at the median of their centroids along the
longest side of the centroids' box, down to at most `LEAF` triangles per leaf (compiled). `closest` walks it depth first, nearer child first, pruning a
box whose distance is not below the best found, the query points in Z-order, each search starting
from the triangle the one before it found; the triangle test is Ericson's
*ClosestPtPointTriangle* (Real-Time Collision Detection §5.1.5), which also gives the closest
point's barycentric coordinates, exactly 0 off the face's interior (on an edge or at a corner),
for the sign by pseudo-normals. Among triangles at equal distance the lowest row wins, so the
answer does not depend on the tree.

The residual's branch and bound (`pipeline.clearance.triangle_depth`) runs here in one compiled
call (`depth`): its corners and its levels' midpoints searched by the same walk, signed by
`acra.pseudonormals.signs`, bounded by eq. (4), (6) and (7), deduplicated and split, each step in
the arithmetic and order of the array form in `pipeline.clearance`, so the answers are the same
bits; a call costs its searches and bounds, without a numpy call per step of a level.

Arrays are float64 unless stated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from acra.pseudonormals import _corner, _row, _signs, flood as _flood, links as _links, representatives as _representatives
from acra.pseudonormals import vertex_normals as _vertex_normals

__all__ = ["LEAF", "Tree", "build", "build_linear", "part_tree", "closest", "distances", "boxes_meet", "faces_meet_rows", "chunk_vertices", "face_chunks",
           "faces_at", "barycentric", "facet_bound", "bounds",
           "first_rows", "distinct_rows", "covering_radii", "lattice_points", "children", "depth"]

LEAF = 4  # triangles per leaf


@dataclass(frozen=True, eq=False)
class Tree:
    """A BVH over triangles ``tri (f, 3, 3)``.

    Attributes
    ----------
    tri : (f, 3, 3) float64
        The triangles, in their given rows.
    order : (f,) int64
        Triangle rows in leaf order: a leaf holds ``order[start : start + count]``.
    lo, hi : (n, 3) float64
        Node boxes; node 0 is the root.
    left, right : (n,) int64
        Children of an inner node; ``-1`` at a leaf.
    start, count : (n,) int64
        A leaf's range in ``order``.
    leaf_tri : (f, 3, 3) float64
        ``tri[order]``: a leaf's triangles side by side in memory.
    """

    tri: np.ndarray
    order: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    left: np.ndarray
    right: np.ndarray
    start: np.ndarray
    count: np.ndarray
    leaf_tri: np.ndarray


@njit(cache=True, nogil=True)
def _before(cen, axis, parent, node, f, g):
    """Whether triangle ``f`` comes before ``g`` in ``node``'s sorted order: by the centroid along
    ``node``'s split axis, equal ones by its parent's order, and so on to the root, then by row."""
    while node >= 0:
        x, y = cen[f, axis[node]], cen[g, axis[node]]
        if x < y:
            return True
        if y < x:
            return False
        node = parent[node]
    return f < g


@njit(cache=True, nogil=True)
def _select(key, cen, axis, parent, node, order, a, b, k):
    """Rearrange ``order[a:b]`` so that ``order[a:k]`` holds the ``k - a`` first triangles of
    ``node``'s order (`_before`, a strict order: no two triangles tie), ``order[k:b]`` the rest.
    ``key[a:b]`` holds each one's centroid along ``node``'s axis and moves with it: the
    comparisons read it side by side in memory, and ``_before`` only for equal keys."""
    up = parent[node]
    lo, hi = a, b - 1
    while hi > lo:
        m = (lo + hi) // 2  # median of three as the pivot, moved to ``hi``
        for x, y in ((m, lo), (hi, lo), (m, hi)):  # swap when ``order[x]`` comes before ``order[y]``
            kx, ky = key[x], key[y]
            if kx < ky or (not ky < kx and _before(cen, axis, parent, up, order[x], order[y])):
                order[x], order[y] = order[y], order[x]
                key[x], key[y] = ky, kx
        pivot, pk = order[hi], key[hi]
        i = lo
        for j in range(lo, hi):
            x = key[j]
            if x < pk or (not pk < x and _before(cen, axis, parent, up, order[j], pivot)):
                order[i], order[j] = order[j], order[i]
                key[i], key[j] = x, key[i]
                i += 1
        order[i], order[hi] = order[hi], order[i]
        key[i], key[hi] = key[hi], key[i]
        if i == k:
            return
        if i < k:
            lo = i + 1
        else:
            hi = i - 1


@njit(cache=True, nogil=True)
def _leaf_box(tlo, thi, order, a, b, lo, hi, node):
    """A leaf's box: the minima and maxima of its triangles' boxes ``order[a:b]``."""
    for k in range(3):
        lo[node, k], hi[node, k] = np.inf, -np.inf
    for s in range(a, b):
        t = order[s]
        for k in range(3):
            lo[node, k] = min(lo[node, k], tlo[t, k])
            hi[node, k] = max(hi[node, k], thi[t, k])


@njit(cache=True, nogil=True)
def _inner_boxes(left, right, lo, hi, nodes):
    """Each inner node's box from its two children's (the same minima and maxima as its
    triangles'); children come after their parent, so a reverse sweep sees them first."""
    for node in range(nodes - 1, -1, -1):
        l, r = left[node], right[node]
        if l >= 0:
            for k in range(3):
                lo[node, k] = min(lo[l, k], lo[r, k])
                hi[node, k] = max(hi[l, k], hi[r, k])


@njit(cache=True, nogil=True)
def _build(tlo, thi, cen, order, lo, hi, left, right, start, count):
    """Median splits along the longest side of each node's centroid box; returns the node count.

    The tree of sorting each node's triangles stably along its split axis (equal centroids in
    the node's order) and halving the sorted list: a node's order is then the centroids along its
    axis, then along its parent's, and so on up to the root, then the row (`_before`). A node
    needs only which triangles make its first half (`_select`, linear), and a leaf its triangles
    in its parent's order, so the tree, the leaves' order and the boxes are those of sorting
    every node, in O(n log n) instead of O(n log^2 n). A leaf's box is taken from its
    triangles, an inner node's from its two children's (the same minima and maxima)."""
    n = order.shape[0]
    axis = np.zeros(2 * n + 1, np.int64)
    parent = np.full(2 * n + 1, -1, np.int64)
    key = np.empty(n)
    stack = np.empty((128, 3), np.int64)  # (node, first, end)
    stack[0, 0], stack[0, 1], stack[0, 2] = 0, 0, n
    top, nodes = 1, 1
    while top > 0:
        top -= 1
        node, a, b = stack[top, 0], stack[top, 1], stack[top, 2]
        if b - a <= LEAF:
            _leaf_box(tlo, thi, order, a, b, lo, hi, node)
            for s in range(a + 1, b):  # its parent's order (the rows at a leaf root)
                f = order[s]
                t = s - 1
                while t >= a and _before(cen, axis, parent, parent[node], f, order[t]):
                    order[t + 1] = order[t]
                    t -= 1
                order[t + 1] = f
            left[node], right[node], start[node], count[node] = -1, -1, a, b - a
            continue
        c0, c1, c2 = np.inf, np.inf, np.inf
        d0, d1, d2 = -np.inf, -np.inf, -np.inf
        for s in range(a, b):
            f = order[s]
            c0, d0 = min(c0, cen[f, 0]), max(d0, cen[f, 0])
            c1, d1 = min(c1, cen[f, 1]), max(d1, cen[f, 1])
            c2, d2 = min(c2, cen[f, 2]), max(d2, cen[f, 2])
        ax, widest = 0, d0 - c0
        if d1 - c1 > widest:
            ax, widest = 1, d1 - c1
        if d2 - c2 > widest:
            ax = 2
        axis[node] = ax
        for s in range(a, b):
            key[s] = cen[order[s], ax]
        mid = (a + b) // 2
        _select(key, cen, axis, parent, node, order, a, b, mid)
        parent[nodes], parent[nodes + 1] = node, node
        left[node], right[node], start[node], count[node] = nodes, nodes + 1, a, 0
        stack[top, 0], stack[top, 1], stack[top, 2] = nodes, a, mid
        stack[top + 1, 0], stack[top + 1, 1], stack[top + 1, 2] = nodes + 1, mid, b
        top += 2
        nodes += 2
    _inner_boxes(left, right, lo, hi, nodes)
    return nodes


@njit(cache=True, nogil=True)
def _boxes_centroids(tri):
    """Each triangle's box and centroid, as ``tri.min(axis=1)``, ``tri.max(axis=1)`` and
    ``tri.mean(axis=1)`` give them (the centroid summed corner by corner, then over 3)."""
    f = tri.shape[0]
    lo, hi, cen = np.empty((f, 3)), np.empty((f, 3)), np.empty((f, 3))
    for i in range(f):
        for k in range(3):
            a, b, c = tri[i, 0, k], tri[i, 1, k], tri[i, 2, k]
            lo[i, k] = min(min(a, b), c)
            hi[i, k] = max(max(a, b), c)
            cen[i, k] = ((a + b) + c) / 3.0
    return lo, hi, cen


def build(tri: np.ndarray) -> Tree:
    """The `Tree` of triangles ``tri (f, 3, 3)`` (``f >= 1``)."""
    tri = np.ascontiguousarray(tri, np.float64).reshape(-1, 3, 3)
    f = len(tri)
    if not f:
        raise ValueError("a BVH needs at least one triangle")
    n = 2 * f + 1
    lo, hi = np.empty((n, 3)), np.empty((n, 3))
    left, right, start, count = (np.empty(n, np.int64) for _ in range(4))
    order = np.arange(f, dtype=np.int64)
    used = _build(*_boxes_centroids(tri), order, lo, hi, left, right, start, count)
    return Tree(tri, order, lo[:used], hi[:used], left[:used], right[:used], start[:used], count[:used], tri[order])


@njit(cache=True, nogil=True)
def _build_linear(vertices, faces, tri, lo, hi, left, right, start, count):
    """`build_linear`'s tree: fills the corners ``tri (f, 3, 3)`` and the node arrays; returns the
    leaf order and the node count."""
    f = faces.shape[0]
    tlo, thi, cen = np.empty((f, 3)), np.empty((f, 3)), np.empty((f, 3))
    for i in range(f):
        for c in range(3):
            v = faces[i, c]
            for k in range(3):
                tri[i, c, k] = vertices[v, k]
        for k in range(3):
            a, b, c = tri[i, 0, k], tri[i, 1, k], tri[i, 2, k]
            tlo[i, k] = min(min(a, b), c)
            thi[i, k] = max(max(a, b), c)
            cen[i, k] = ((a + b) + c) / 3.0
    key = _morton_keys(cen)
    order = _stable_order(key)
    stack = np.empty((128, 3), np.int64)  # (node, first, end); at most 30 bit levels + log2(f) deep
    stack[0, 0], stack[0, 1], stack[0, 2] = 0, 0, f
    top, nodes = 1, 1
    while top > 0:
        top -= 1
        node, a, b = stack[top, 0], stack[top, 1], stack[top, 2]
        if b - a <= LEAF:
            _leaf_box(tlo, thi, order, a, b, lo, hi, node)
            left[node], right[node], start[node], count[node] = -1, -1, a, b - a
            continue
        first, last = key[order[a]], key[order[b - 1]]
        mid = (a + b) // 2  # one code throughout: halve the run
        if first != last:  # the codes share their bits above the highest that differs: split where it turns 1
            bit = 0
            while (first ^ last) >> (bit + 1):
                bit += 1
            i, j = a, b - 1  # key[order[i]] has the bit clear, key[order[j]] set
            while j - i > 1:
                m = (i + j) // 2
                if (key[order[m]] >> bit) & 1:
                    j = m
                else:
                    i = m
            mid = j
        left[node], right[node], start[node], count[node] = nodes, nodes + 1, a, 0
        stack[top, 0], stack[top, 1], stack[top, 2] = nodes, a, mid
        stack[top + 1, 0], stack[top + 1, 1], stack[top + 1, 2] = nodes + 1, mid, b
        top += 2
        nodes += 2
    _inner_boxes(left, right, lo, hi, nodes)
    return order, nodes


@njit(cache=True, nogil=True)
def _gather(tri, order, out):
    for s in range(order.shape[0]):
        for c in range(3):
            for k in range(3):
                out[s, c, k] = tri[order[s], c, k]


def build_linear(vertices: np.ndarray, faces: np.ndarray) -> Tree:
    """A `Tree` of the triangles ``vertices[faces]`` (``vertices (n, 3)``, ``faces (f, 3) int64``,
    ``f >= 1``) built in linear time, for a set queried about once (a part solid of a round):
    the triangles sorted once along a Z-order curve over their centroids (`_morton_keys`), each
    node split where the highest bit in which its codes differ turns from 0 to 1, so each node
    holds the triangles of one cell of the octree over their box. `closest`'s answer (least
    distance, lowest row among equal ones) does not depend on the tree, only how many boxes it
    opens: about 5 % more than on `build`'s median splits (the spike's and the head's parts,
    ``benchmarks/residual_calls.py``), at a third of the build's cost."""
    v = np.ascontiguousarray(vertices, np.float64).reshape(-1, 3)
    fc = np.ascontiguousarray(faces, np.int64).reshape(-1, 3)
    f = len(fc)
    if not f:
        raise ValueError("a BVH needs at least one triangle")
    n = 2 * f + 1
    tri = np.empty((f, 3, 3))
    lo, hi = np.empty((n, 3)), np.empty((n, 3))
    left, right, start, count = (np.empty(n, np.int64) for _ in range(4))
    order, used = _build_linear(v, fc, tri, lo, hi, left, right, start, count)
    leaf_tri = np.empty((f, 3, 3))
    _gather(tri, order, leaf_tri)
    return Tree(tri, order, lo[:used], hi[:used], left[:used], right[:used], start[:used], count[:used], leaf_tri)


@njit(cache=True, nogil=True)
def _part_tree(vertices, faces, normals, angle):
    """`part_tree`'s arrays: the vertex normals, the box, then `build_linear`'s corners, leaf
    order, node arrays (``2 f + 1`` rows, the first ``used`` filled), ``used`` and leaf corners."""
    vn = _vertex_normals(vertices.shape[0], faces, normals, angle)
    box = np.empty((2, 3))
    _bounds(vertices, box)
    f = faces.shape[0]
    n = 2 * f + 1
    tri = np.empty((f, 3, 3))
    lo, hi = np.empty((n, 3)), np.empty((n, 3))
    left, right, start, count = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    order, used = _build_linear(vertices, faces, tri, lo, hi, left, right, start, count)
    leaf_tri = np.empty((f, 3, 3))
    _gather(tri, order, leaf_tri)
    return vn, box, tri, order, lo, hi, left, right, start, count, used, leaf_tri


def part_tree(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, angle: np.ndarray):
    """What a part solid (`pipeline.clearance.solid` with ``part``) builds past its mesh, in one
    compiled call: the angle-weighted vertex normals ``(n, 3)`` (`acra.pseudonormals.vertex_normals`
    of the face ``normals (f, 3)`` and corner ``angle (f, 3)``), the box ``(2, 3)`` of ``vertices
    (n, 3)`` (`bounds`) and `build_linear`'s `Tree` of ``vertices[faces]`` (``faces (f, 3) int64``,
    ``f >= 1``, C-contiguous): the same arrays, without a call and its arguments' checks each."""
    vn, box, tri, order, lo, hi, left, right, start, count, used, leaf_tri = _part_tree(vertices, faces, normals, angle)
    return vn, box, Tree(tri, order, lo[:used], hi[:used], left[:used], right[:used], start[:used], count[:used], leaf_tri)


@njit(cache=True, nogil=True)
def _point_triangle(p, a, b, c):
    """Closest point of triangle ``abc`` to ``p`` and its barycentric weights (Ericson 5.1.5):
    ``(x, y, z, wa, wb, wc)``. Each of ``p, a, b, c`` is a ``(3,)`` array or a tuple of 3 floats
    (`_row`, `_corner`): the same arithmetic either way."""
    ab0, ab1, ab2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    ac0, ac1, ac2 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    ap0, ap1, ap2 = p[0] - a[0], p[1] - a[1], p[2] - a[2]
    d1 = ab0 * ap0 + ab1 * ap1 + ab2 * ap2
    d2 = ac0 * ap0 + ac1 * ap1 + ac2 * ap2
    if d1 <= 0.0 and d2 <= 0.0:
        return a[0], a[1], a[2], 1.0, 0.0, 0.0
    bp0, bp1, bp2 = p[0] - b[0], p[1] - b[1], p[2] - b[2]
    d3 = ab0 * bp0 + ab1 * bp1 + ab2 * bp2
    d4 = ac0 * bp0 + ac1 * bp1 + ac2 * bp2
    if d3 >= 0.0 and d4 <= d3:
        return b[0], b[1], b[2], 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        return a[0] + t * ab0, a[1] + t * ab1, a[2] + t * ab2, 1.0 - t, t, 0.0
    cp0, cp1, cp2 = p[0] - c[0], p[1] - c[1], p[2] - c[2]
    d5 = ab0 * cp0 + ab1 * cp1 + ab2 * cp2
    d6 = ac0 * cp0 + ac1 * cp1 + ac2 * cp2
    if d6 >= 0.0 and d5 <= d6:
        return c[0], c[1], c[2], 0.0, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        return a[0] + t * ac0, a[1] + t * ac1, a[2] + t * ac2, 1.0 - t, 0.0, t
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return b[0] + t * (c[0] - b[0]), b[1] + t * (c[1] - b[1]), b[2] + t * (c[2] - b[2]), 0.0, 1.0 - t, t
    denom = va + vb + vc
    if denom == 0.0:  # a degenerate triangle: its closest corner
        best, x, y, z, wa, wb, wc = np.inf, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        for k in range(3):
            q = a if k == 0 else (b if k == 1 else c)
            d = (p[0] - q[0]) ** 2 + (p[1] - q[1]) ** 2 + (p[2] - q[2]) ** 2
            if d < best:
                best, x, y, z = d, q[0], q[1], q[2]
                wa, wb, wc = (1.0, 0.0, 0.0) if k == 0 else ((0.0, 1.0, 0.0) if k == 1 else (0.0, 0.0, 1.0))
        return x, y, z, wa, wb, wc
    v = vb / denom
    w = vc / denom
    return a[0] + ab0 * v + ac0 * w, a[1] + ab1 * v + ac1 * w, a[2] + ab2 * v + ac2 * w, 1.0 - v - w, v, w


@njit(cache=True, nogil=True)
def _box_distance(p, lo, hi, node):
    d = 0.0
    for k in range(3):
        if p[k] < lo[node, k]:
            d += (lo[node, k] - p[k]) ** 2
        elif p[k] > hi[node, k]:
            d += (p[k] - hi[node, k]) ** 2
    return d


@njit(cache=True, nogil=True)
def _morton_order(points):
    """Rows of ``points (k, 3)`` along a Z-order curve over their box (10 bits an axis)."""
    return _stable_order(_morton_keys(points))


@njit(cache=True, nogil=True)
def _morton_keys(points):
    """The 30-bit Z-order code ``(k,) int64`` of each of ``points (k, 3)`` over their box: each
    axis in 1024 steps of its side, bit ``b`` of axis ``a`` at bit ``3 b + a``."""
    k = points.shape[0]
    lo = np.empty(3)
    span = np.empty(3)
    for a in range(3):
        lo[a], m = np.inf, -np.inf
        for i in range(k):
            lo[a] = min(lo[a], points[i, a])
            m = max(m, points[i, a])
        span[a] = m - lo[a]
    key = np.zeros(k, np.int64)
    for i in range(k):
        code = 0
        for a in range(3):
            q = 0
            if span[a] > 0.0:
                q = int((points[i, a] - lo[a]) / span[a] * 1023.0)
                q = min(max(q, 0), 1023)
            code |= _spread(q) << a
        key[i] = code
    return key


@njit(cache=True, nogil=True)
def _spread(q):
    """The 10 bits of ``q`` moved from bit ``b`` to bit ``3 b`` (four masked shifts)."""
    q = (q | (q << 16)) & 0x030000FF
    q = (q | (q << 8)) & 0x0300F00F
    q = (q | (q << 4)) & 0x030C30C3
    return (q | (q << 2)) & 0x09249249


_RADIX_MIN = 64  # fewer keys than this: a merge sort beats the radix passes' bucket tables


@njit(cache=True, nogil=True)
def _stable_order(key):
    """``np.argsort(key, kind="mergesort")`` of 30-bit keys ``(k,) int64 >= 0``: a stable sort has
    one answer (equal keys by row), so three stable 10-bit counting passes (least significant
    first) give the same rows, in linear time."""
    k = key.shape[0]
    if k < _RADIX_MIN:
        return np.argsort(key, kind="mergesort")
    order, spare = np.arange(k), np.empty(k, np.int64)
    count = np.empty(1025, np.int64)
    for shift in range(0, 30, 10):
        count[:] = 0
        for i in range(k):
            count[((key[i] >> shift) & 1023) + 1] += 1
        for b in range(1024):
            count[b + 1] += count[b]
        for i in range(k):
            r = order[i]
            d = (key[r] >> shift) & 1023
            spare[count[d]] = r
            count[d] += 1
        order, spare = spare, order
    return order


@njit(cache=True, nogil=True)
def _closest(tri, order, lo, hi, left, right, start, count, points, bound, dist, close, face, bary):
    # tri is the tree's leaf_tri; a node's box distance is computed once, when its parent
    # pushes it, and held against the best distance when it is popped. The points are visited
    # along a Z-order curve and each starts from the triangle its predecessor found: a near
    # first best prunes most boxes at once. The answer is the least distance and, among equal
    # ones, the lowest row, whichever triangle the search starts from.
    stack = np.empty(256, np.int64)
    near = np.empty(256)
    seq = _morton_order(points)
    seed = -1  # leaf slot of the previous point's closest triangle
    for j in range(points.shape[0]):
        i = seq[j]
        p = _row(points, i)
        best = bound[i] * bound[i]
        best_face, best_slot = -1, -1
        bx, by, bz, ba, bb, bc = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        if seed >= 0:
            x, y, z, wa, wb, wc = _point_triangle(p, _corner(tri, seed, 0), _corner(tri, seed, 1), _corner(tri, seed, 2))
            dd = (p[0] - x) ** 2 + (p[1] - y) ** 2 + (p[2] - z) ** 2
            if dd <= best:
                best, best_face, best_slot = dd, order[seed], seed
                bx, by, bz, ba, bb, bc = x, y, z, wa, wb, wc
        stack[0] = 0
        near[0] = _box_distance(p, lo, hi, np.int64(0))  # int64: a literal 0 compiles a specialisation of its own
        top = 1
        while top > 0:
            top -= 1
            node = stack[top]
            if near[top] > best:
                continue
            if left[node] < 0:
                for s in range(start[node], start[node] + count[node]):
                    # the triangle's own box first, as a node's: a triangle whose box is farther
                    # than the best (about half of a leaf's) needs no exact test
                    near_box = 0.0
                    for k in range(3):
                        low = min(min(tri[s, 0, k], tri[s, 1, k]), tri[s, 2, k])
                        high = max(max(tri[s, 0, k], tri[s, 1, k]), tri[s, 2, k])
                        if p[k] < low:
                            near_box += (low - p[k]) ** 2
                        elif p[k] > high:
                            near_box += (p[k] - high) ** 2
                    if near_box > best:
                        continue
                    f = order[s]
                    x, y, z, wa, wb, wc = _point_triangle(p, _corner(tri, s, 0), _corner(tri, s, 1), _corner(tri, s, 2))
                    dd = (p[0] - x) ** 2 + (p[1] - y) ** 2 + (p[2] - z) ** 2
                    if dd < best or (dd == best and (best_face < 0 or f < best_face)):
                        best, best_face, best_slot = dd, f, s
                        bx, by, bz, ba, bb, bc = x, y, z, wa, wb, wc
                continue
            a, b = left[node], right[node]
            da, db = _box_distance(p, lo, hi, a), _box_distance(p, lo, hi, b)
            # the nearer child last on the stack, so it is visited first
            if da <= db:
                stack[top], stack[top + 1] = b, a
                near[top], near[top + 1] = db, da
            else:
                stack[top], stack[top + 1] = a, b
                near[top], near[top + 1] = da, db
            top += 2
        if best_face >= 0:
            seed = best_slot
            dist[i] = np.sqrt(best)
            close[i, 0], close[i, 1], close[i, 2] = bx, by, bz
            face[i] = best_face
            bary[i, 0], bary[i, 1], bary[i, 2] = ba, bb, bc

def closest(tree: Tree, points: np.ndarray, bound: np.ndarray | None = None):
    """Exact closest points on ``tree``'s triangles to ``points (k, 3)``.

    Returns
    -------
    dist : (k,) float64
        ``inf`` where nothing is nearer than ``bound (k,)`` (if given).
    close : (k, 3) float64
    face : (k,) int64
        Row of the triangle (lowest among equally near ones); ``-1`` where none.
    bary : (k, 3) float64
        Barycentric weights of the closest point in that triangle; a weight is exactly 0 when the
        point lies on the opposite edge's line segment (an edge or a corner).
    """
    p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    k = len(p)
    dist, close = np.full(k, np.inf), np.zeros((k, 3))
    face, bary = np.full(k, -1, np.int64), np.zeros((k, 3))
    b = np.full(k, np.inf) if bound is None else np.ascontiguousarray(bound, np.float64).reshape(k)
    if k:
        _closest(tree.leaf_tri, tree.order, tree.lo, tree.hi, tree.left, tree.right, tree.start, tree.count, p, b, dist, close,
                 face, bary)
    return dist, close, face, bary


@njit(cache=True, nogil=True)
def _distances(points, tri, out):
    for i in range(points.shape[0]):
        x, y, z, _, _, _ = _point_triangle(_row(points, i), _corner(tri, i, 0), _corner(tri, i, 1), _corner(tri, i, 2))
        out[i] = np.sqrt((points[i, 0] - x) ** 2 + (points[i, 1] - y) ** 2 + (points[i, 2] - z) ** 2)


def distances(points: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Distance ``(k,) float64`` from each of ``points (k, 3)`` to its triangle ``tri (k, 3, 3)``."""
    p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    t = np.ascontiguousarray(tri, np.float64).reshape(-1, 3, 3)
    out = np.empty(len(p))
    if len(p):
        _distances(p, t, out)
    return out


@njit(cache=True, nogil=True)
def _boxes_meet(tri, lo, hi, pad, out):
    for i in range(tri.shape[0]):
        meet = True
        for k in range(3):
            a, b, c = tri[i, 0, k], tri[i, 1, k], tri[i, 2, k]
            if not (min(min(a, b), c) <= hi[k] + pad and lo[k] <= max(max(a, b), c) + pad):
                meet = False
                break
        out[i] = meet


def boxes_meet(tri: np.ndarray, lo: np.ndarray, hi: np.ndarray, pad: float = 0.0) -> np.ndarray:
    """Whether the box of each of triangles ``tri (f, 3, 3)`` comes within ``pad`` of the box
    ``lo, hi (3,)``: ``(f,) bool``, the comparisons of ``grids.overlap`` on the corners' minima
    and maxima, in one pass without the boxes' arrays."""
    t = np.ascontiguousarray(tri, np.float64).reshape(-1, 3, 3)
    out = np.empty(len(t), np.bool_)
    if len(t):
        _boxes_meet(t, np.ascontiguousarray(lo, np.float64).reshape(3), np.ascontiguousarray(hi, np.float64).reshape(3),
                    float(pad), out)
    return out


def _read_only(faces: np.ndarray) -> np.ndarray:
    """``faces`` as C-contiguous int64, read-only (a view where it is writeable): a display's
    triangles turn read-only once digested (`pipeline.residual`), and numba compiles a kernel once
    per writeability, so the kernels that take them see one kind."""
    f = np.ascontiguousarray(faces, np.int64)
    if f.flags.writeable:
        f = f.view()
        f.flags.writeable = False
    return f


@njit(inline="always")
def _beyond(points, v, lo0, lo1, lo2, top0, top1, top2, pad):
    # point ``v``'s side bits against the box padded by ``pad`` (``top`` = ``hi + pad``): bits 1,
    # 4, 16 where it lies below the box on x, y, z, bits 2, 8, 32 where above
    x, y, z = points[v, 0], points[v, 1], points[v, 2]
    bits = 0
    if not lo0 <= x + pad:
        bits |= 1
    if not x <= top0:
        bits |= 2
    if not lo1 <= y + pad:
        bits |= 4
    if not y <= top1:
        bits |= 8
    if not lo2 <= z + pad:
        bits |= 16
    if not z <= top2:
        bits |= 32
    return bits


@njit(cache=True, nogil=True)
def _faces_meet_rows(points, faces, lo, hi, pad, beyond, out):
    # a face's box misses the padded box on an axis exactly when all three corners lie beyond the
    # same side: ``min <= hi + pad`` holds iff some corner is ``<= hi + pad``, and ``lo <= max + pad``
    # iff some corner has ``lo <= x + pad`` (rounding ``x + pad`` is monotone in ``x``, so it
    # commutes with the max). So each point is compared once, a bit per side per axis, and a face
    # meets the box unless its corners' bits share one.
    top0, top1, top2 = hi[0] + pad, hi[1] + pad, hi[2] + pad
    lo0, lo1, lo2 = lo[0], lo[1], lo[2]
    for v in range(points.shape[0]):
        beyond[v] = _beyond(points, v, lo0, lo1, lo2, top0, top1, top2, pad)
    n = 0
    for i in range(faces.shape[0]):
        if beyond[faces[i, 0]] & beyond[faces[i, 1]] & beyond[faces[i, 2]] == 0:
            out[n] = i
            n += 1
    return n


def faces_meet_rows(points: np.ndarray, faces: np.ndarray, lo: np.ndarray, hi: np.ndarray, pad: float = 0.0,
                    chunks: tuple | None = None) -> np.ndarray:
    """The rows ``(m,) int64`` of ``faces`` (``(f, 3) int64`` into ``points (n, 3) float64``, finite)
    whose triangles' boxes come within ``pad`` of the box ``lo, hi`` (`boxes_meet`'s comparisons,
    the same answers), in increasing order, without gathering the triangles: each point is
    compared with the box once, however many faces share it. With ``chunks`` (`face_chunks` of
    these points and faces) only the faces of the chunks whose boxes come within ``pad`` are
    compared, the same rows."""
    out = np.empty(len(faces), np.int64)
    n = 0
    if len(faces):
        p = np.ascontiguousarray(points, np.float64)
        lo3, hi3 = np.ascontiguousarray(lo, np.float64).reshape(3), np.ascontiguousarray(hi, np.float64).reshape(3)
        if chunks is None:
            n = _faces_meet_rows(p, _read_only(faces), lo3, hi3, float(pad), np.empty(len(p), np.uint8), out)
        else:
            n = _faces_meet_chunks(p, _read_only(faces), CHUNK, *chunks, lo3, hi3, float(pad), out)
    return out[:n].copy()


CHUNK = 32  # `face_chunks`: consecutive faces a chunk, consecutive chunks a group


@njit(cache=True, nogil=True)
def _chunk_vertices(faces, size, n, start, verts):
    seen = np.full(n, -1, np.int64)  # the last chunk each point was listed for
    k = 0
    for c in range(start.shape[0] - 1):
        start[c] = k
        for i in range(c * size, min((c + 1) * size, faces.shape[0])):
            for j in range(3):
                v = faces[i, j]
                if seen[v] != c:
                    seen[v] = c
                    verts[k] = v
                    k += 1
    start[start.shape[0] - 1] = k
    return k


def chunk_vertices(faces: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The points each chunk of `CHUNK` consecutive rows of ``faces (f, 3) int64`` (into ``n``
    points) uses, once each: ``(start (c + 1,) int64, verts (k,) int64)``, chunk ``c``'s points
    ``verts[start[c]:start[c + 1]]``. A function of the faces alone: a display's topology gives
    it to every display on it (`face_chunks`)."""
    nc = -(-len(faces) // CHUNK)
    start, verts = np.zeros(nc + 1, np.int64), np.empty(3 * len(faces), np.int64)
    k = _chunk_vertices(_read_only(faces), CHUNK, int(n), start, verts) if len(faces) else 0
    return start, verts[:k].copy()


@njit(cache=True, nogil=True)
def _face_chunks(points, start, verts, size, clo, chi, glo, ghi):
    nc = clo.shape[0]
    for c in range(nc):
        a0, a1, a2, b0, b1, b2 = np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf
        for r in range(start[c], start[c + 1]):
            v = verts[r]
            x, y, z = points[v, 0], points[v, 1], points[v, 2]
            a0, b0 = min(a0, x), max(b0, x)
            a1, b1 = min(a1, y), max(b1, y)
            a2, b2 = min(a2, z), max(b2, z)
        clo[c, 0], clo[c, 1], clo[c, 2], chi[c, 0], chi[c, 1], chi[c, 2] = a0, a1, a2, b0, b1, b2
    for g in range(glo.shape[0]):
        a0, a1, a2, b0, b1, b2 = np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf
        for c in range(g * size, min((g + 1) * size, nc)):
            a0, a1, a2 = min(a0, clo[c, 0]), min(a1, clo[c, 1]), min(a2, clo[c, 2])
            b0, b1, b2 = max(b0, chi[c, 0]), max(b1, chi[c, 1]), max(b2, chi[c, 2])
        glo[g, 0], glo[g, 1], glo[g, 2], ghi[g, 0], ghi[g, 1], ghi[g, 2] = a0, a1, a2, b0, b1, b2


def face_chunks(points: np.ndarray, used: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Boxes of a mesh's faces in chunks of `CHUNK` consecutive rows, and of those chunks in
    groups of `CHUNK`, for `faces_meet_rows`: ``(lo (c, 3), hi (c, 3), group_lo (g, 3), group_hi
    (g, 3))`` float64, the minima and maxima of the points ``points (n, 3) float64`` (finite) each
    chunk's faces use (``used``, `chunk_vertices` of the faces). A display's rows run along its
    surface, so a chunk's faces lie together and a query near a contact opens a few chunks
    instead of comparing every point."""
    start, verts = used
    nc = len(start) - 1
    ng = -(-nc // CHUNK)
    clo, chi, glo, ghi = np.empty((nc, 3)), np.empty((nc, 3)), np.empty((ng, 3)), np.empty((ng, 3))
    if nc:
        _face_chunks(np.ascontiguousarray(points, np.float64), start, verts, CHUNK, clo, chi, glo, ghi)
    return clo, chi, glo, ghi


@njit(cache=True, nogil=True)
def _faces_meet_chunks(points, faces, size, clo, chi, glo, ghi, lo, hi, pad, out):
    # `_faces_meet_rows`' comparisons, face by face, in the chunks and groups that may hold a face
    # meeting the box: a face lacks a side's bit when one of its corners does (``x <= hi + pad``,
    # ``lo <= x + pad``), and then its chunk's least ``x`` (at most that corner's) is ``<= hi +
    # pad`` and ``lo <=`` its largest ``x`` plus ``pad`` (the rounding of ``x + pad`` is monotone
    # in ``x``): a box missing that is skipped with every face in it
    top0, top1, top2 = hi[0] + pad, hi[1] + pad, hi[2] + pad
    lo0, lo1, lo2 = lo[0], lo[1], lo[2]
    nf, nc = faces.shape[0], clo.shape[0]
    n = 0
    for g in range(glo.shape[0]):
        if not (glo[g, 0] <= top0 and glo[g, 1] <= top1 and glo[g, 2] <= top2 and lo0 <= ghi[g, 0] + pad
                and lo1 <= ghi[g, 1] + pad and lo2 <= ghi[g, 2] + pad):
            continue
        for c in range(g * size, min((g + 1) * size, nc)):
            if not (clo[c, 0] <= top0 and clo[c, 1] <= top1 and clo[c, 2] <= top2 and lo0 <= chi[c, 0] + pad
                    and lo1 <= chi[c, 1] + pad and lo2 <= chi[c, 2] + pad):
                continue
            for i in range(c * size, min((c + 1) * size, nf)):
                shared = 63
                for j in range(3):
                    shared &= _beyond(points, faces[i, j], lo0, lo1, lo2, top0, top1, top2, pad)
                if shared == 0:
                    out[n] = i
                    n += 1
    return n


@njit(cache=True, nogil=True)
def _faces_at(points, faces, rows, out):
    for i in range(rows.shape[0]):
        for c in range(3):
            v = faces[rows[i], c]
            for k in range(3):
                out[i, c, k] = points[v, k]


def faces_at(points: np.ndarray, faces: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``points[faces[rows]]`` ``(m, 3, 3) float64`` (``points (n, 3) float64``, ``faces (f, 3)
    int64``, ``rows (m,) int64`` in range), copied in one compiled pass."""
    out = np.empty((len(rows), 3, 3))
    if len(rows):
        _faces_at(np.ascontiguousarray(points, np.float64), _read_only(faces),
                  np.ascontiguousarray(rows, np.int64), out)
    return out


@njit(cache=True, nogil=True)
def _barycentric(bary, tri, corners, rows, faces, values, points, at):
    # numpy's einsum("mk,mkc->mc") arithmetic: each output summed from 0.0 (so a -0.0 sum comes
    # out as 0.0), corner by corner
    for i in range(bary.shape[0]):
        t = tri[i]
        w0, w1, w2 = bary[i, 0], bary[i, 1], bary[i, 2]
        for c in range(3):
            points[i, c] = ((0.0 + w0 * corners[t, 0, c]) + w1 * corners[t, 1, c]) + w2 * corners[t, 2, c]
        if at.shape[0]:
            f0, f1, f2 = faces[rows[t], 0], faces[rows[t], 1], faces[rows[t], 2]
            for c in range(values.shape[1]):
                at[i, c] = ((0.0 + w0 * values[f0, c]) + w1 * values[f1, c]) + w2 * values[f2, c]


def barycentric(bary: np.ndarray, tri: np.ndarray, corners: np.ndarray, rows: np.ndarray, faces: np.ndarray,
                values: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """The points at barycentric weights ``bary (m, 3)`` in triangles ``corners[tri] ((t, 3, 3),
    tri (m,) int64)``, and, given per-vertex ``values (n, c)``, the values there in the faces
    ``faces[rows[tri]]`` (``faces (f, 3) int64`` into them, ``rows (t,) int64``), in one compiled
    pass: ``np.einsum("mk,mkc->mc", bary, corners[tri])`` and ``np.einsum("mk,mkc->mc", bary,
    values[faces[rows[tri]]])`` to the bit. Returns ``(points (m, 3), at (m, c) or None)``."""
    m = len(bary)
    points = np.empty((m, 3))
    v = np.zeros((0, 2)) if values is None else np.ascontiguousarray(values, np.float64)
    if v.flags.writeable:  # one writeability, so the kernel is compiled once (`_read_only`)
        v = v.view()
        v.flags.writeable = False
    at = np.empty((m if values is not None else 0, v.shape[1]))
    if m:
        _barycentric(np.ascontiguousarray(bary, np.float64), np.ascontiguousarray(tri, np.int64),
                     np.ascontiguousarray(corners, np.float64), np.ascontiguousarray(rows, np.int64), _read_only(faces), v,
                     points, at)
    return points, None if values is None else at


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
def _bounds(points, out):
    for k in range(3):
        out[0, k], out[1, k] = points[0, k], points[0, k]
    for i in range(1, points.shape[0]):
        for k in range(3):
            x = points[i, k]
            if x < out[0, k]:
                out[0, k] = x
            if x > out[1, k]:
                out[1, k] = x


def bounds(points: np.ndarray) -> np.ndarray:
    """The box ``(2, 3)`` (min and max corner) of ``points (..., 3)``, as ``min(axis=0)`` and
    ``max(axis=0)`` give it, in one pass (numpy reduces a short last axis row by row)."""
    p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    if not len(p):
        return np.stack([p.min(axis=0), p.max(axis=0)])  # raises, as numpy does
    out = np.empty((2, 3))
    _bounds(p, out)
    return out


@njit(cache=True, nogil=True)
def _first_rows(bits, first, label):
    size = 1
    while size < 2 * bits.shape[0]:
        size *= 2
    table = np.full(size, -1, np.int64)
    mask = np.uint64(size - 1)
    u = 0
    for i in range(bits.shape[0]):
        h = (bits[i, 0] * np.uint64(0x9E3779B97F4A7C15)) ^ (bits[i, 1] * np.uint64(0xC2B2AE3D27D4EB4F)) \
            ^ (bits[i, 2] * np.uint64(0x165667B19E3779F9))
        h ^= h >> np.uint64(31)
        slot = np.int64(h & mask)
        while True:
            j = table[slot]
            if j < 0:
                table[slot] = u
                first[u] = i
                label[i] = u
                u += 1
                break
            r = first[j]
            if bits[r, 0] == bits[i, 0] and bits[r, 1] == bits[i, 1] and bits[r, 2] == bits[i, 2]:
                label[i] = j
                break
            slot = (slot + 1) & (size - 1)
    return u


def first_rows(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bitwise distinct rows of ``points (k, 3) float64`` by a hash table: the row ``(u,)
    int64`` of each one's first occurrence, in the order of first occurrence, and each row's
    index ``(k,) int64`` into them."""
    bits = np.ascontiguousarray(points, np.float64).reshape(-1, 3).view(np.uint64)
    first, label = np.empty(len(bits), np.int64), np.empty(len(bits), np.int64)
    u = _first_rows(bits, first, label) if len(bits) else 0
    return first[:u], label


@njit(cache=True, nogil=True)
def _swapped(x):
    """The bytes of ``x (uint64)`` in reverse order: a little-endian value's first byte most
    significant, so unsigned order is the order of the 8 bytes as stored (memcmp's)."""
    y = np.uint64(0)
    for _ in range(8):
        y = (y << np.uint64(8)) | (x & np.uint64(255))
        x = x >> np.uint64(8)
    return y


@njit(cache=True, nogil=True)
def _distinct_rows(bits, first, inverse):
    # the distinct rows in order of first occurrence (`_first_rows`), then sorted by their
    # 24 bytes as stored: x's bytes, then y's, then z's (no two distinct rows tie)
    k = bits.shape[0]
    once, label = np.empty(k, np.int64), np.empty(k, np.int64)
    u = _first_rows(bits, once, label)
    key = np.empty((u, 3), np.uint64)
    for j in range(u):
        for c in range(3):
            key[j, c] = _swapped(bits[once[j], c])
    # the stable sort of the x keys over int64 (the sign bit flipped: the same order as uint64),
    # the one key type every kernel's merge sort takes, so a first run compiles numba's
    # argsort once (about 1.5 s CPU for a second key type)
    signed = np.empty(u, np.int64)
    for j in range(u):
        signed[j] = np.int64(key[j, 0] ^ np.uint64(0x8000000000000000))
    order = np.argsort(signed, kind="mergesort")
    a = 0
    while a < u:  # a run of equal x: by y, then z (insertion; runs are short)
        b = a + 1
        while b < u and key[order[b], 0] == key[order[a], 0]:
            b += 1
        for i in range(a + 1, b):
            r = order[i]
            t = i - 1
            while t >= a and (key[order[t], 1] > key[r, 1] or (key[order[t], 1] == key[r, 1] and key[order[t], 2] > key[r, 2])):
                order[t + 1] = order[t]
                t -= 1
            order[t + 1] = r
        a = b
    rank = np.empty(u, np.int64)
    for r in range(u):
        rank[order[r]] = r
        first[r] = once[order[r]]
    for i in range(k):
        inverse[i] = rank[label[i]]
    return u


def distinct_rows(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bitwise distinct rows of ``points (k, 3) float64`` in the order ``np.unique`` gives
    rows viewed as 24 raw bytes (memcmp; -0.0 and 0.0 distinct): the row ``(u,) int64`` of each
    one's first occurrence and each row's index ``(k,) int64`` into them (``np.unique``'s
    ``return_index`` and ``return_inverse``)."""
    bits = np.ascontiguousarray(points, np.float64).reshape(-1, 3).view(np.uint64)
    first, inverse = np.empty(len(bits), np.int64), np.empty(len(bits), np.int64)
    u = _distinct_rows(bits, first, inverse) if len(bits) else 0
    return first[:u], inverse


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
            tol, facet, facet_start, facet_faces, planes):
    # `pipeline.clearance`'s branch and bound from level 0 on, the level-0 cells' eq. (4) given
    # as ``bound``; each step in the arithmetic and order of its array form (`_levels`),
    # so the answers are the same bits. A maximum is exact whatever the order of its terms, so
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
           facet_faces, planes):
    # `pipeline.clearance._triangle_depth`'s level 0 (its corners, `_signed_corners`) in the
    # arithmetic and order of its array form, then the levels past it (`_refine`)
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
        facet, facet_start, facet_faces, planes)
    return (code, retired, low, complete, evaluated, level, np.concatenate((in_tri, f_tri)), np.concatenate((in_lat, f_lat)),
            np.concatenate((in_pts, f_pts)), np.concatenate((in_sd, f_sd)))


def depth(tri, box, part: bool, reach: float, target: float, decide: float, max_split: int, budget: int, far: float,
          link: float, tree: Tree, vertices, faces, normals, edge_normals, vertex_normals, tol: float, facet, facet_start,
          facet_faces, planes=None):
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

    Returns ``None`` if a point is unresolved, else ``(bound, low, complete, evaluated, level,
    tri (m,) int64, lattice (m, 3) int64, points (m, 3), depth (m,))``: the certified bound, the
    largest depth found (``-inf`` if no point), whether every cell ended within its target, the
    points evaluated, the split depth, and the points found inside, in order, with their
    integer barycentric weights (times ``1 << max_split``)."""
    out = _depth(np.ascontiguousarray(tri, np.float64).reshape(-1, 3, 3), np.ascontiguousarray(box[0], np.float64),
                 np.ascontiguousarray(box[1], np.float64), bool(part), float(reach), float(target), float(decide),
                 int(max_split), int(budget), float(far), float(link), tree.leaf_tri, tree.order, tree.lo, tree.hi, tree.left,
                 tree.right, tree.start, tree.count, vertices, faces, normals, edge_normals, vertex_normals, float(tol), facet,
                 facet_start, facet_faces, _NO_PLANES if planes is None else np.ascontiguousarray(planes, np.int64))
    return None if out[0] else out[1:]
