"""Distances to the nearest of a point set, through a compiled kd-tree, in scipy's arithmetic.

A query's distance is ``sqrt((dx² + dy²) + dz²)`` to its nearest point, the squares summed in
that order, as ``scipy.spatial.cKDTree.query`` computes it (the same bits): the least of these
sums is the same number whatever tree finds it, and a square root keeps the order. The tree
splits each node's points at the median of its widest side until at most `LEAF` are left; the
search goes depth first, nearer side first, and passes over a cell whose distance from the
query (the squares of its offsets from the split planes bounding it, one per axis, summed)
exceeds the least sum found by more than 1e-12 of it: every point in the cell is at least that
far, and the rounding of either sum is far within that margin. Points can be masked out of a tree, so a set that differs from a tree's by a few
points is the tree masked and a small tree of the others (`pipeline.shape.CoarseIndex`).
Arrays are float64 unless stated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = ["LEAF", "PointTree", "build", "nearest_squares", "thin_greedy"]

LEAF = 8  # points a leaf holds at most


@dataclass(frozen=True, eq=False)
class PointTree:
    """A kd-tree of ``points (n, 3)``: ``order (n,) int64`` the points' rows in leaf order,
    ``sorted (n, 3)`` the points in that order, and per node ``start, stop (m,) int64`` its
    range in ``order``, ``dim (m,) int64`` its split axis, ``split (m,)`` its split value and
    ``left (m,) int64`` its first child (the second follows it; ``-1``: a leaf)."""

    points: np.ndarray
    order: np.ndarray
    sorted: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    dim: np.ndarray
    split: np.ndarray
    left: np.ndarray

    @property
    def n(self) -> int:
        return len(self.points)


@njit(cache=True, nogil=True)
def _select(pts, order, a, b, m, d):
    """Reorder ``order[a:b + 1]`` so that row ``m`` holds the point of its rank along axis ``d``,
    those before it none greater and those after none less (Hoare's selection)."""
    while b > a:
        pivot = pts[order[(a + b) // 2], d]
        i, j = a, b
        while i <= j:
            while pts[order[i], d] < pivot:
                i += 1
            while pts[order[j], d] > pivot:
                j -= 1
            if i <= j:
                order[i], order[j] = order[j], order[i]
                i += 1
                j -= 1
        if m <= j:
            b = j
        elif m >= i:
            a = i
        else:
            return


@njit(cache=True, nogil=True)
def _build(pts, order, start, stop, dim, split, left):
    n = len(order)
    nodes = 1
    start[0], stop[0] = 0, n
    stack = np.empty(128, np.int64)
    stack[0] = 0
    top = 1
    while top:
        top -= 1
        node = stack[top]
        a, b = start[node], stop[node]
        left[node] = -1
        if b - a <= LEAF:
            continue
        # d starts as an int64, not the literal 0: typing would otherwise compile `_select` once
        # for the literal and once for the axis the loop picks
        best, d = -1.0, np.int64(0)
        for k in range(3):
            lo, hi = np.inf, -np.inf
            for i in range(a, b):
                x = pts[order[i], k]
                lo, hi = min(lo, x), max(hi, x)
            if hi - lo > best:
                best, d = hi - lo, k
        if not best > 0.0:  # every point the same: one leaf
            continue
        m = (a + b) // 2
        _select(pts, order, a, b - 1, m, d)
        dim[node], split[node] = d, pts[order[m], d]  # left holds x_d <= split, right x_d >= split
        left[node] = nodes
        start[nodes], stop[nodes] = a, m
        start[nodes + 1], stop[nodes + 1] = m, b
        stack[top], stack[top + 1] = nodes + 1, nodes
        top += 2
        nodes += 2
    return nodes


def build(points: np.ndarray) -> PointTree:
    """The `PointTree` of ``points (n, 3)``."""
    pts = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    n = len(pts)
    size = max(1, 2 * n)
    order = np.arange(n, dtype=np.int64)
    start, stop, dim, left = (np.zeros(size, np.int64) for _ in range(4))
    split = np.zeros(size)
    m = _build(pts, order, start, stop, dim, split, left) if n else 1
    return PointTree(pts, order, np.ascontiguousarray(pts[order]), start[:m], stop[:m], dim[:m], split[:m], left[:m])


@njit(cache=True, nogil=True)
def _nearest(sorted_pts, keep, start, stop, dim, split, left, q, best_in, out):
    depth = 256
    nodes = np.empty(depth, np.int64)
    offs = np.zeros((depth, 3))  # per stacked node: the query's offset from its cell, per axis
    for j in range(q.shape[0]):
        x, y, z = q[j, 0], q[j, 1], q[j, 2]
        best = best_in[j]
        nodes[0] = 0
        offs[0, 0] = offs[0, 1] = offs[0, 2] = 0.0
        top = 1
        while top:
            top -= 1
            node = nodes[top]
            o0, o1, o2 = offs[top, 0], offs[top, 1], offs[top, 2]
            if (o0 * o0 + o1 * o1 + o2 * o2) * (1.0 - 1e-12) > best:
                continue  # the cell is farther than the best (with room for rounding)
            c = left[node]
            if c < 0:
                for i in range(start[node], stop[node]):
                    if keep[i]:
                        dx, dy, dz = x - sorted_pts[i, 0], y - sorted_pts[i, 1], z - sorted_pts[i, 2]
                        s = dx * dx + dy * dy + dz * dz
                        if s < best:
                            best = s
                continue
            d = dim[node]
            off = q[j, d] - split[node]
            near, far = (c, c + 1) if off < 0.0 else (c + 1, c)
            nodes[top] = far
            offs[top, 0], offs[top, 1], offs[top, 2] = o0, o1, o2
            offs[top, d] = off
            top += 1
            nodes[top] = near
            offs[top, 0], offs[top, 1], offs[top, 2] = o0, o1, o2
            top += 1
        out[j] = best


def nearest_squares(tree: PointTree, q: np.ndarray, keep: np.ndarray | None = None,
                    best: np.ndarray | None = None) -> np.ndarray:
    """For points ``q (k, 3)``: the least ``(dx² + dy²) + dz²`` ``(k,)`` to a point of ``tree``
    whose row ``keep (n,) bool`` holds (``None``: every point) and ``best (k,)`` (``None``:
    ``inf``); ``inf`` where none is nearer."""
    q = np.ascontiguousarray(q, np.float64).reshape(-1, 3)
    best = np.full(len(q), np.inf) if best is None else np.ascontiguousarray(best, np.float64)
    out = np.empty(len(q))
    if not tree.n:
        out[:] = best
        return out
    kept = np.ones(tree.n, np.bool_) if keep is None else np.ascontiguousarray(keep[tree.order])
    _nearest(tree.sorted, kept, tree.start, tree.stop, tree.dim, tree.split, tree.left, q, best, out)
    return out


@njit(cache=True, nogil=True)
def _thin_greedy(points, r2, keep):
    g = points.shape[0]
    for i in range(g):
        if not keep[i]:
            continue
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        for j in range(i + 1, g):
            if keep[j]:
                d0, d1, d2 = x - points[j, 0], y - points[j, 1], z - points[j, 2]
                if d0 * d0 + d1 * d1 + d2 * d2 <= r2:
                    keep[j] = False


def thin_greedy(points: np.ndarray, radius: float, keep: np.ndarray) -> np.ndarray:
    """Greedy thinning of ``points (g, 3)`` in row order, in place on ``keep (g,) bool``: each
    row still kept drops every later row within ``radius`` of it, the pair's offsets ``p_i -
    p_j`` squared and summed in coordinate order against ``radius * radius`` (the test of the
    array form ``(d0 * d0 + d1 * d1) + d2 * d2 <= radius * radius`` over every pair ``i < j``, the
    same bits). One pass over the pairs of a frame's few dozen points, where the array form
    builds three ``(g, g)`` arrays and walks the rows in Python. Returns ``keep``."""
    if len(points) > 1:
        _thin_greedy(np.ascontiguousarray(points, np.float64).reshape(-1, 3), float(radius) * float(radius), keep)
    return keep
