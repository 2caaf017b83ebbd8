"""Exact closest points on a triangle set in trimesh's arithmetic, through a compiled BVH.

Detection decides inside and depth by the closest point of a collision grid
(`pipeline.grids.Closest`): the least distance over the triangles and, among equal ones, the
lowest triangle row. The triangle test is trimesh's ``triangles.closest_point`` (Ericson's
*ClosestPtPointTriangle*, Real-Time Collision Detection §5.1.5, with trimesh's tolerance
``1e-13`` on the region tests and its segment rule for a triangle whose first two corners
coincide), done on the coordinates divided by a unit of the mesh's size and the answer
multiplied back, in numpy's operation order: each dot product summed corner term by term, the
face point ``(a + ab v) + ac w`` with ``v, w`` from one reciprocal, the distance the square root
of the squares summed in order. So each (point, triangle) distance is the same bits as the
array form's, and so is the answer.

The search walks `acra.bvh`'s tree (median splits, at most `acra.bvh.LEAF` triangles a leaf)
depth first, nearer child first, the points along a Z-order curve, each starting from the
triangle its predecessor found. A box is opened while its distance is within the best
distance found plus ``1e-9`` of it and ``1e-12`` of the unit: a box's distance bounds its
triangles' from below, and a computed distance is within rounding (``1e-16`` relative) of the
true one, so no triangle that could hold or tie the least computed distance is passed over,
whatever the order of the search. Arrays are float64 unless stated.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from acra.bvh import LEAF, Tree, _bounds, _morton_order
from acra.halfspaces import _within as _halfspaces_within
from acra.kdtree import PointTree
from acra.kdtree import _nearest as _kd_nearest
from acra.patch_boxes import _within as _boxes_within
from acra.pseudonormals import _corner

__all__ = ["ZERO", "Index", "build", "candidates", "closest_points", "corners", "face_uv", "index", "query", "refit"]

ZERO = 1e-13  # trimesh.constants.tol.zero: the region tests' tolerance, in units of the mesh
_REL, _ABS = 1e-9, 1e-12  # a box is opened within best * (1 + _REL) + _ABS * unit


@njit(cache=True, nogil=True)
def _build(tri, lo, hi, left, right, start, count):
    """A linear BVH: the triangles sorted once along a Z-order curve over their centroids, each
    node's range split at its middle (the boxes are `_boxes`'). Returns the leaf order and the
    node count. Its shape only decides how fast `query` finds the answer, never which one."""
    f = tri.shape[0]
    cen = np.empty((f, 3))
    for i in range(f):
        for k in range(3):
            cen[i, k] = (tri[i, 0, k] + tri[i, 1, k] + tri[i, 2, k]) / 3.0
    order = _morton_order(cen)
    stack = np.empty((128, 3), np.int64)  # (node, first, end)
    stack[0, 0], stack[0, 1], stack[0, 2] = 0, 0, f
    top, nodes = 1, 1
    while top > 0:
        top -= 1
        node, a, b = stack[top, 0], stack[top, 1], stack[top, 2]
        if b - a <= LEAF:
            left[node], right[node], start[node], count[node] = -1, -1, a, b - a
            continue
        mid = (a + b) // 2
        left[node], right[node], start[node], count[node] = nodes, nodes + 1, a, 0
        stack[top, 0], stack[top, 1], stack[top, 2] = nodes, a, mid
        stack[top + 1, 0], stack[top + 1, 1], stack[top + 1, 2] = nodes + 1, mid, b
        top += 2
        nodes += 2
    return order, nodes


@njit(cache=True, nogil=True)
def _boxes(leaf_tri, lo, hi, left, right, start, count, nodes):
    """The node boxes of a tree whose leaves hold ``leaf_tri`` (the triangles in leaf order): a
    leaf's from its triangles' corners, read in a row, an inner node's from its children's;
    children are numbered after their parent, so boxes go in reverse numbering. Minima and maxima
    are exact: the same boxes in any order of reading."""
    for node in range(nodes - 1, -1, -1):
        x0, y0, z0, x1, y1, z1 = np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf
        if left[node] < 0:
            for s in range(start[node], start[node] + count[node]):
                for c in range(3):
                    x, y, z = leaf_tri[s, c, 0], leaf_tri[s, c, 1], leaf_tri[s, c, 2]
                    x0, y0, z0 = min(x0, x), min(y0, y), min(z0, z)
                    x1, y1, z1 = max(x1, x), max(y1, y), max(z1, z)
        else:
            for child in (left[node], right[node]):
                x0, y0, z0 = min(x0, lo[child, 0]), min(y0, lo[child, 1]), min(z0, lo[child, 2])
                x1, y1, z1 = max(x1, hi[child, 0]), max(y1, hi[child, 1]), max(z1, hi[child, 2])
        lo[node, 0], lo[node, 1], lo[node, 2] = x0, y0, z0
        hi[node, 0], hi[node, 1], hi[node, 2] = x1, y1, z1


@njit(cache=True, nogil=True)
def _corners(vertices, faces, out):
    for i in range(faces.shape[0]):
        for c in range(3):
            v = faces[i, c]
            for k in range(3):
                out[i, c, k] = vertices[v, k]


def corners(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``vertices[faces]``: the corners ``(f, 3, 3) float64`` of ``faces (f, 3)`` (indices in
    range, non-negative) on ``vertices (n, 3) float64``, copied in one compiled pass (numpy's
    fancy index copies row by row through its generic iterator)."""
    vertices = np.asarray(vertices)
    faces = np.asarray(faces)
    if (vertices.dtype != np.float64 or vertices.ndim != 2 or vertices.shape[1] != 3 or faces.dtype.kind not in "iu"
            or faces.ndim != 2 or faces.shape[1] != 3):
        return vertices[faces]
    out = np.empty((faces.shape[0], 3, 3))
    if len(faces):
        _corners(np.ascontiguousarray(vertices), np.ascontiguousarray(faces, np.int64), out)
    return out


def _in_order(tri: np.ndarray, order: np.ndarray) -> np.ndarray:
    """``tri[order]`` for triangles ``tri (f, 3, 3)`` and rows ``order (f,) int64``, the same
    copy through ``np.take`` along the first axis, which copies each row's 9 values as one block
    (numpy's fancy index of a 3-d array walks them one by one: 4 times as long)."""
    return np.take(tri, order, axis=0)


def build(tri: np.ndarray) -> Tree:
    """The linear BVH (`acra.bvh.Tree`) of triangles ``tri (f, 3, 3)`` (``f >= 1``)."""
    tri = np.ascontiguousarray(tri, np.float64).reshape(-1, 3, 3)
    if not len(tri):
        raise ValueError("a BVH needs at least one triangle")
    n = 2 * len(tri) + 1
    lo, hi = np.empty((n, 3)), np.empty((n, 3))
    left, right, start, count = (np.empty(n, np.int64) for _ in range(4))
    order, used = _build(tri, lo, hi, left, right, start, count)
    leaf = _in_order(tri, order)
    _boxes(leaf, lo, hi, left, right, start, count, used)
    return Tree(order, lo[:used], hi[:used], left[:used], right[:used], start[:used], count[:used], leaf)


def refit(tree: Tree, tri: np.ndarray) -> Tree:
    """``tree``'s leaves and nodes over new triangles ``tri (f, 3, 3)`` (the same rows, moved),
    their boxes taken again: the tree `query` walks for ``tri``, without the Z-order sort and
    splits of `build`. The boxes are exact, so `query` gives the answer it gives on ``build(tri)``
    (the least distance and, among equal ones, the lowest row, whatever the tree)."""
    tri = np.ascontiguousarray(tri, np.float64).reshape(-1, 3, 3)
    if len(tri) != len(tree.order):
        raise ValueError("refit needs the tree's triangle count")
    lo, hi = np.empty_like(tree.lo), np.empty_like(tree.hi)
    leaf = _in_order(tri, tree.order)
    _boxes(leaf, lo, hi, tree.left, tree.right, tree.start, tree.count, len(lo))
    return Tree(tree.order, lo, hi, tree.left, tree.right, tree.start, tree.count, leaf)


class Index:
    """A triangle set ready for `query`: the linear BVH of ``tri (f, 3, 3)`` (`build`, or with
    ``like`` an `Index` of as many triangles, its tree `refit`) and its leaf triangles divided by
    ``unit`` (the same bits as dividing the gathered rows)."""

    def __init__(self, tri: np.ndarray, unit: float, like: "Index | None" = None) -> None:
        self.tree: Tree = build(tri) if like is None else refit(like.tree, tri)
        self.unit = float(unit)
        self.leaf_units = self.tree.leaf_tri / self.unit


def index(tri: np.ndarray, unit: float, like: Index | None = None) -> Index:
    """The `Index` of triangles ``tri (f, 3, 3)`` (``f >= 1``) in units of ``unit``; with ``like``
    (an `Index` of the same rows before they moved), its tree refitted (`refit`)."""
    return Index(tri, unit, like)


@njit(cache=True, nogil=True)
def _closest_units(p0, p1, p2, a, b, c, zero):
    """trimesh's ``closest_point`` of the point ``p`` and the triangle of corners ``a, b, c``
    (tuples of 3 values; both in units). Corners as values, not the triangle array: the compiled
    walk calls this function (too large to be inlined), and an array handed to it has its
    reference count taken and dropped around each exact test, a cost of the order of the test's
    arithmetic (*Kernels* in ``docs/performance.md``)."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    c0, c1, c2 = c
    ab0, ab1, ab2 = b0 - a0, b1 - a1, b2 - a2
    ac0, ac1, ac2 = c0 - a0, c1 - a1, c2 - a2
    ap0, ap1, ap2 = p0 - a0, p1 - a1, p2 - a2
    d1 = ab0 * ap0 + ab1 * ap1 + ab2 * ap2
    d2 = ac0 * ap0 + ac1 * ap1 + ac2 * ap2
    if ab0 == 0.0 and ab1 == 0.0 and ab2 == 0.0:
        # a and b coincide: the segment ac (trimesh handles it before every region but a's,
        # whose answer it then overwrites)
        length = ac0 * ac0 + ac1 * ac1 + ac2 * ac2
        f = 0.0
        if length > 0.0:
            f = (ap0 * ac0 + ap1 * ac1 + ap2 * ac2) / length
        f = min(max(f, 0.0), 1.0)
        return a0 + f * ac0, a1 + f * ac1, a2 + f * ac2
    if d1 < zero and d2 < zero:
        return a0, a1, a2
    bp0, bp1, bp2 = p0 - b0, p1 - b1, p2 - b2
    d3 = ab0 * bp0 + ab1 * bp1 + ab2 * bp2
    d4 = ac0 * bp0 + ac1 * bp1 + ac2 * bp2
    if d3 > -zero and d4 <= d3:
        return b0, b1, b2
    vc = d1 * d4 - d3 * d2
    if vc < zero and d1 > -zero and d3 < zero:
        v = d1 / (d1 - d3)
        return a0 + v * ab0, a1 + v * ab1, a2 + v * ab2
    cp0, cp1, cp2 = p0 - c0, p1 - c1, p2 - c2
    d5 = ab0 * cp0 + ab1 * cp1 + ab2 * cp2
    d6 = ac0 * cp0 + ac1 * cp1 + ac2 * cp2
    if d6 > -zero and d5 <= d6:
        return c0, c1, c2
    vb = d5 * d2 - d1 * d6
    if vb < zero and d2 > -zero and d6 < zero:
        w = d2 / (d2 - d6)
        return a0 + w * ac0, a1 + w * ac1, a2 + w * ac2
    va = d3 * d6 - d5 * d4
    if va < zero and (d4 - d3) > -zero and (d5 - d6) > -zero:
        d43 = d4 - d3
        w = d43 / (d43 + (d5 - d6))
        return b0 + w * (c0 - b0), b1 + w * (c1 - b1), b2 + w * (c2 - b2)
    denom = 1.0 / (va + vb + vc)
    v = vb * denom
    w = vc * denom
    return a0 + ab0 * v + ac0 * w, a1 + ab1 * v + ac1 * w, a2 + ab2 * v + ac2 * w


@njit(cache=True, nogil=True)
def _distance(points, i, t, s, unit, zero):
    """Distance, in the caller's units, from ``points[i]`` to triangle ``t[s]`` (in units of
    ``unit``) and its closest point: ``unit * closest_point(t / unit, p / unit)``, then the norm."""
    p0, p1, p2 = points[i, 0], points[i, 1], points[i, 2]
    a, b, c = _corner(t, s, 0), _corner(t, s, 1), _corner(t, s, 2)
    x, y, z = _closest_units(p0 / unit, p1 / unit, p2 / unit, a, b, c, zero)
    x, y, z = unit * x, unit * y, unit * z
    dx, dy, dz = x - p0, y - p1, z - p2
    return np.sqrt(dx * dx + dy * dy + dz * dz), x, y, z


@njit(cache=True, nogil=True)
def _box_square(points, i, lo, hi, node):
    """The squared distance from ``points[i]`` to the box ``lo[node], hi[node]``."""
    d = 0.0
    for k in range(3):
        p = points[i, k]
        if p < lo[node, k]:
            d += (lo[node, k] - p) ** 2
        elif p > hi[node, k]:
            d += (p - hi[node, k]) ** 2
    return d


@njit(cache=True, nogil=True)
def _triangle_square(points, i, w, s):
    """The squared distance from ``points[i]`` to the box of triangle ``w[s] (3, 3)``."""
    d = 0.0
    for k in range(3):
        p = points[i, k]
        a, b, c = w[s, 0, k], w[s, 1, k], w[s, 2, k]
        low = min(a, min(b, c))
        if p < low:
            d += (low - p) ** 2
            continue
        high = max(a, max(b, c))
        if p > high:
            d += (p - high) ** 2
    return d


@njit(cache=True, nogil=True)
def _query(t, w, order, lo, hi, left, right, start, count, unit, zero, points, bound, dist, close, face):
    # the least (distance, row) pair; a box is opened while its distance is within `reach` of
    # the best distance, so the answer does not depend on where the search starts. Boxes are
    # compared by squared distances against the squared reach: the reach's margin (1e-9 of the
    # best distance) is far above the rounding of the squares, so no box that the distances
    # themselves would open is passed over. A triangle of an opened leaf (``w``: the leaf
    # triangles in the caller's units, ``t``: in units of ``unit``) is measured only where its
    # own box lies within the reach: its box bounds its distance from below as a node's does.
    stack = np.empty(256, np.int64)
    near = np.empty(256)
    seq = _morton_order(points)
    # int64, not literals (here and the root below): a literal argument compiles a specialisation
    # of `_distance` and `_box_square` of its own in the first run
    seed = np.int64(-1)  # leaf slot of the previous point's closest triangle
    slack = _ABS * unit
    for j in range(points.shape[0]):
        i = seq[j]
        best, best_face = bound[i], -1
        bx, by, bz = 0.0, 0.0, 0.0
        if seed >= 0:
            d, x, y, z = _distance(points, i, t, seed, unit, zero)
            if d <= best:
                best, best_face, bx, by, bz = d, order[seed], x, y, z
        stack[0] = 0
        near[0] = _box_square(points, i, lo, hi, np.int64(0))
        top = 1
        while top > 0:
            top -= 1
            node = stack[top]
            reach = best * (1.0 + _REL) + slack
            if near[top] > reach * reach:
                continue
            if left[node] < 0:
                for s in range(start[node], start[node] + count[node]):
                    within = best * (1.0 + _REL) + slack
                    if _triangle_square(points, i, w, s) > within * within:
                        continue
                    f = order[s]
                    d, x, y, z = _distance(points, i, t, s, unit, zero)
                    if d < best or (d == best and (best_face < 0 or f < best_face)):
                        best, best_face, seed, bx, by, bz = d, f, s, x, y, z
                continue
            a, b = left[node], right[node]
            da, db = _box_square(points, i, lo, hi, a), _box_square(points, i, lo, hi, b)
            if da <= db:  # the nearer child last on the stack, so it is visited first
                stack[top], stack[top + 1] = b, a
                near[top], near[top + 1] = db, da
            else:
                stack[top], stack[top + 1] = a, b
                near[top], near[top + 1] = da, db
            top += 2
        if best_face >= 0:
            dist[i] = best
            close[i, 0], close[i, 1], close[i, 2] = bx, by, bz
            face[i] = best_face


def query(idx: Index, points: np.ndarray, bound: np.ndarray | None = None):
    """Closest points on ``idx``'s triangles to ``points (k, 3)``.

    Returns
    -------
    dist : (k,) float64
        The least distance (trimesh's arithmetic); ``inf`` where no triangle is within
        ``bound (k,)`` (if given).
    close : (k, 3) float64
        The closest points (zeros where none).
    face : (k,) int64
        Row of the triangle, the lowest among equally near ones (0 where none).
    """
    p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    k = len(p)
    dist, close, face = np.full(k, np.inf), np.zeros((k, 3)), np.zeros(k, np.int64)
    b = np.full(k, np.inf) if bound is None else np.ascontiguousarray(bound, np.float64).reshape(k)
    if k:
        tr = idx.tree
        _query(idx.leaf_units, tr.leaf_tri, tr.order, tr.lo, tr.hi, tr.left, tr.right, tr.start, tr.count, idx.unit, ZERO, p, b, dist,
               close, face)
    return dist, close, face


@njit(cache=True, nogil=True)
def _pairs(tri_units, points, unit, zero, dist, close):
    for i in range(points.shape[0]):
        d, x, y, z = _distance(points, i, tri_units, i, unit, zero)
        dist[i] = d
        close[i, 0], close[i, 1], close[i, 2] = x, y, z


def closest_points(tri: np.ndarray, points: np.ndarray, unit: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Distances ``(k,)`` and closest points ``(k, 3)`` of ``points (k, 3)`` on their own
    triangles ``tri (k, 3, 3)``: ``unit * trimesh.triangles.closest_point(tri / unit, points /
    unit)`` and the norm of its offset, the same bits, one pass."""
    p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    t = np.ascontiguousarray(tri, np.float64).reshape(-1, 3, 3) / float(unit)
    dist, close = np.empty(len(p)), np.empty((len(p), 3))
    if len(p):
        _pairs(t, p, float(unit), ZERO, dist, close)
    return dist, close


@njit(cache=True, nogil=True, error_model="numpy")
def _face_uv(points, uv, triangles, face, close, lo, hi, out):
    for k in range(face.shape[0]):
        f = face[k]
        a, b, c = triangles[f, 0], triangles[f, 1], triangles[f, 2]
        e0x, e0y, e0z = points[b, 0] - points[a, 0], points[b, 1] - points[a, 1], points[b, 2] - points[a, 2]
        e1x, e1y, e1z = points[c, 0] - points[a, 0], points[c, 1] - points[a, 1], points[c, 2] - points[a, 2]
        wx, wy, wz = close[k, 0] - points[a, 0], close[k, 1] - points[a, 1], close[k, 2] - points[a, 2]
        d00 = e0x * e0x + e0y * e0y + e0z * e0z
        d01 = e0x * e1x + e0y * e1y + e0z * e1z
        d02 = e0x * wx + e0y * wy + e0z * wz
        d11 = e1x * e1x + e1y * e1y + e1z * e1z
        d12 = e1x * wx + e1y * wy + e1z * wz
        inv = 1.0 / (d00 * d11 - d01 * d01)
        b2 = (d00 * d12 - d01 * d02) * inv
        b1 = (d11 * d02 - d01 * d12) * inv
        b0 = 1 - b1 - b2
        for j in range(2):
            v = 0.0 + b0 * uv[a, j]  # the einsum's zeroed sum: -0.0 terms give 0.0
            v = v + b1 * uv[b, j]
            v = v + b2 * uv[c, j]
            if v == v:  # np.clip: maximum then minimum, each keeping its first argument on ties
                v = v if v >= lo[f, j] else lo[f, j]
                v = v if v <= hi[f, j] else hi[f, j]
            out[k, j] = v


def face_uv(points: np.ndarray, uv: np.ndarray, triangles: np.ndarray, face: np.ndarray, close: np.ndarray,
            lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Parameters ``(k, 2)`` of points ``close (k, 3)`` on faces ``face (k,) int64`` (rows of
    ``triangles (f, 3) int64`` over ``points (n, 3)`` with parameters ``uv (n, 2)``), clipped to
    each face's box ``lo, hi (f, 2)``: ``np.clip(np.einsum("kj,kjc->kc", bary, uv[tri]), lo[face],
    hi[face])`` with ``bary`` trimesh's ``points_to_barycentric`` (Cramer's rule), the same bits:
    each dot product summed term by term as ``trimesh.util.diagonal_dot``'s matrix product and the
    einsum sum them, one reciprocal of the determinant, ``(1 - b1) - b2``."""
    out = np.empty((len(face), 2))
    if len(face):
        _face_uv(np.ascontiguousarray(points, np.float64), np.ascontiguousarray(uv, np.float64),
                 np.ascontiguousarray(triangles, np.int64), np.ascontiguousarray(face, np.int64),
                 np.ascontiguousarray(close, np.float64), np.ascontiguousarray(lo, np.float64),
                 np.ascontiguousarray(hi, np.float64), out)
    return out


# --- which patches can hold a batch's closest points --------------------------------------------
@njit(cache=True, nogil=True)
def _candidates(q, equations, slack, ex_pts, ex_keep, ex_start, ex_stop, ex_dim, ex_split, ex_left,
                pts, keep, start, stop, dim, split, left, lo, hi):
    k = q.shape[0]
    ok = np.ones(k, np.bool_)
    if equations.shape[0]:
        _halfspaces_within(equations, q, slack, ok)
    m = 0
    for i in range(k):
        m += ok[i]
    rows = np.empty(m, np.int64)
    qc = np.empty((m, 3))
    m = 0
    for i in range(k):
        if ok[i]:
            rows[m] = i
            qc[m, 0], qc[m, 1], qc[m, 2] = q[i, 0], q[i, 1], q[i, 2]
            m += 1
    if m == 0:
        return rows, qc, np.empty(0, np.int64)
    best = np.full(m, np.inf)
    if ex_pts.shape[0]:
        found = np.empty(m)
        _kd_nearest(ex_pts, ex_keep, ex_start, ex_stop, ex_dim, ex_split, ex_left, qc, best, found)
        best = found
    squares = best
    if pts.shape[0]:
        squares = np.empty(m)
        _kd_nearest(pts, keep, start, stop, dim, split, left, qc, best, squares)
    limit = np.empty(m)
    most = np.sqrt(squares[0])
    big = 0.0
    for i in range(m):
        d = np.sqrt(squares[i])
        if d > most or d != d:  # numpy's max: a NaN wins
            most = d
        size = max(abs(qc[i, 0]), abs(qc[i, 1]), abs(qc[i, 2]))
        big = max(big, size)
        limit[i] = d * (1 + 1e-9) + ROUNDING * size + 1e-300
    reach = most * (1 + 1e-9) + ROUNDING * big + 1e-300
    box = np.empty((2, 3))
    _bounds(qc, box)
    q_lo0, q_lo1, q_lo2 = box[0, 0] - reach, box[0, 1] - reach, box[0, 2] - reach
    q_hi0, q_hi1, q_hi2 = box[1, 0] + reach, box[1, 1] + reach, box[1, 2] + reach
    pre = np.empty(lo.shape[0], np.int64)
    n = 0
    for p in range(lo.shape[0]):
        if (lo[p, 0] <= q_hi0 and q_lo0 <= hi[p, 0] and lo[p, 1] <= q_hi1 and q_lo1 <= hi[p, 1]
                and lo[p, 2] <= q_hi2 and q_lo2 <= hi[p, 2]):
            pre[n] = p
            n += 1
    lo_pre, hi_pre = np.empty((n, 3)), np.empty((n, 3))
    for j in range(n):
        for a in range(3):
            lo_pre[j, a], hi_pre[j, a] = lo[pre[j], a], hi[pre[j], a]
    near = np.zeros(n, np.bool_)
    if n:
        _boxes_within(lo_pre, hi_pre, qc, limit, near)
    count = 0
    for j in range(n):
        count += near[j]
    patches = np.empty(count, np.int64)
    count = 0
    for j in range(n):
        if near[j]:
            patches[count] = pre[j]
            count += 1
    return rows, qc, patches


_NO_HULL = np.zeros((0, 4))
ROUNDING = 1e-12  # `candidates`' bound past the coarse distance, over a point's largest coordinate magnitude


def candidates(q: np.ndarray, equations: np.ndarray | None, slack: float, extra: PointTree | None, tree: PointTree,
               keep: np.ndarray | None, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The front of a closest-point search on a closed surface's patches, in one compiled pass.

    Of object-space points ``q (k, 3)``, the rows ``(m,) int64`` within ``slack`` of every
    half-space of ``equations (h, 4)`` (`acra.halfspaces.within`; ``None``: every row) and those
    points ``(m, 3)``; then the rows ``(c,) int64``, ascending, of the boxes ``lo, hi (P, 3)``
    that can hold one of their closest points: the distance to the nearest coarse point bounds
    each point's (``sqrt`` of the least square over the points of ``extra`` and of ``tree``
    whose rows ``keep (n,) bool`` hold, `acra.kdtree.nearest_squares`; ``None``: no ``extra``,
    every row), the boxes overlapping the points' box widened by the largest bound
    (`pipeline.grids.overlap`), then those within a point's bound (`acra.patch_boxes.boxes_within`),
    each bound ``d * (1 + 1e-9) + ROUNDING * s + 1e-300``, ``s`` the point's largest coordinate
    magnitude (the box's widening: the largest ``d`` and ``s``). The same arithmetic as those
    steps in turn, so the same rows.

    The ``ROUNDING * s`` term keeps the bound above the rounding of the points themselves: a
    point on a flat patch lies on its coarse point (``d = 0``) and in its box, whose thickness
    is 0, yet the evaluated point and the box's CV coordinates differ in their last bits, and
    a bound of ``d`` alone would leave every box out."""
    q = np.ascontiguousarray(q, np.float64).reshape(-1, 3)
    hull = _NO_HULL if equations is None else np.ascontiguousarray(equations, np.float64)
    if extra is None:
        extra, ex_keep = tree, np.zeros(0, np.bool_)
        ex = (np.zeros((0, 3)), ex_keep, extra.start, extra.stop, extra.dim, extra.split, extra.left)
    else:
        ex = (extra.sorted, np.ones(extra.n, np.bool_), extra.start, extra.stop, extra.dim, extra.split, extra.left)
    kept = np.ones(tree.n, np.bool_) if keep is None else np.ascontiguousarray(keep[tree.order])
    return _candidates(q, hull, float(slack), *ex, tree.sorted, kept, tree.start, tree.stop, tree.dim, tree.split,
                       tree.left, np.ascontiguousarray(lo, np.float64), np.ascontiguousarray(hi, np.float64))
