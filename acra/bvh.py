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

The tree serves the residual's branch and bound (`acra.depthbound`), whose corners and
midpoints it searches with the same walk, and the part solids' trees (`part_tree`, built in
linear time on a Z-order curve, `build_linear`).

Arrays are float64 unless stated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from acra.pseudonormals import _corner, _row, vertex_normals as _vertex_normals

__all__ = ["LEAF", "Tree", "build", "build_linear", "part_tree", "closest", "distances", "bounds"]


LEAF = 4  # triangles per leaf


@dataclass(frozen=True, eq=False)
class Tree:
    """A BVH over triangles ``tri (f, 3, 3)`` (`tri`, from its leaves: the walks read ``leaf_tri``).

    Attributes
    ----------
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

    order: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    left: np.ndarray
    right: np.ndarray
    start: np.ndarray
    count: np.ndarray
    leaf_tri: np.ndarray

    @property
    def tri(self) -> np.ndarray:
        """The triangles ``(f, 3, 3) float64`` in their given rows: ``leaf_tri`` put back in place
        (``tri[order] = leaf_tri``). Only ``leaf_tri`` is kept: the walks read nothing else, and
        a part's tree is built from its vertices and faces without a copy in the given rows."""
        out = np.empty_like(self.leaf_tri)
        out[self.order] = self.leaf_tri
        return out


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
    return Tree(order, lo[:used], hi[:used], left[:used], right[:used], start[:used], count[:used], tri[order])


@njit(cache=True, nogil=True)
def _build_linear(vertices, faces, lo, hi, left, right, start, count):
    """`build_linear`'s tree: fills the node arrays; returns the leaf order and the node count.
    Each face's box and centroid are read from its corners' rows of ``vertices``: the values
    ``vertices[faces]`` holds, without that copy."""
    f = faces.shape[0]
    tlo, thi, cen = np.empty((f, 3)), np.empty((f, 3)), np.empty((f, 3))
    for i in range(f):
        p, q, r = faces[i, 0], faces[i, 1], faces[i, 2]
        for k in range(3):
            a, b, c = vertices[p, k], vertices[q, k], vertices[r, k]
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
def _gather(vertices, faces, order, out):
    """The corners of ``faces[order]`` on ``vertices`` into ``out (f, 3, 3)``: a leaf's triangles
    side by side."""
    for s in range(order.shape[0]):
        for c in range(3):
            v = faces[order[s], c]
            for k in range(3):
                out[s, c, k] = vertices[v, k]


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
    lo, hi = np.empty((n, 3)), np.empty((n, 3))
    left, right, start, count = (np.empty(n, np.int64) for _ in range(4))
    order, used = _build_linear(v, fc, lo, hi, left, right, start, count)
    leaf_tri = np.empty((f, 3, 3))
    _gather(v, fc, order, leaf_tri)
    return Tree(order, lo[:used], hi[:used], left[:used], right[:used], start[:used], count[:used], leaf_tri)


@njit(cache=True, nogil=True)
def _part_tree(vertices, faces, normals, angle):
    """`part_tree`'s arrays: the vertex normals, the box, then `build_linear`'s leaf order, node
    arrays (``2 f + 1`` rows, the first ``used`` filled), ``used`` and leaf corners."""
    vn = _vertex_normals(vertices.shape[0], faces, normals, angle)
    box = np.empty((2, 3))
    _bounds(vertices, box)
    f = faces.shape[0]
    n = 2 * f + 1
    lo, hi = np.empty((n, 3)), np.empty((n, 3))
    left, right, start, count = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    order, used = _build_linear(vertices, faces, lo, hi, left, right, start, count)
    leaf_tri = np.empty((f, 3, 3))
    _gather(vertices, faces, order, leaf_tri)
    return vn, box, order, lo, hi, left, right, start, count, used, leaf_tri


def part_tree(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, angle: np.ndarray):
    """What a part solid (`pipeline.clearance.solid` with ``part``) builds past its mesh, in one
    compiled call: the angle-weighted vertex normals ``(n, 3)`` (`acra.pseudonormals.vertex_normals`
    of the face ``normals (f, 3)`` and corner ``angle (f, 3)``), the box ``(2, 3)`` of ``vertices
    (n, 3)`` (`bounds`) and `build_linear`'s `Tree` of ``vertices[faces]`` (``faces (f, 3) int64``,
    ``f >= 1``, C-contiguous): the same arrays, without a call and its arguments' checks each."""
    vn, box, order, lo, hi, left, right, start, count, used, leaf_tri = _part_tree(vertices, faces, normals, angle)
    return vn, box, Tree(order, lo[:used], hi[:used], left[:used], right[:used], start[:used], count[:used], leaf_tri)


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
def _bounds(points, out):
    for k in range(3):
        out[0, k], out[1, k] = points[0, k], points[0, k]
    for i in range(1, points.shape[0]):
        for k in range(3):
            x = points[i, k]
            # numpy's minimum and maximum: a NaN wins, and no comparison lets a later value replace it
            if x < out[0, k] or x != x:
                out[0, k] = x
            if x > out[1, k] or x != x:
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
